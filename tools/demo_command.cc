#include <cstdio>

#include "command.h"
#include "rolamos/demo_store.hpp"
#include "util/memory.h"
#include "util/progress.h"

namespace rolamos::cli {

struct DemoSwitches {
  std::string output = "demo.rolamos";
  long long size = 16384;
  TiffSwitches tiff;
  bool quiet = false;
};

static int RunDemo(const DemoSwitches& s) {
  DemoOptions o;
  o.store = s.output;
  o.width = o.height = s.size;
  o.tiff = ToWriteOptions(s.tiff);
  Progress progress("demo", s.quiet);
  DemoResult r = WriteDemoStore(o, [&](double f) { progress.Update(f); });
  progress.Done();
  const double seconds = progress.ElapsedSeconds();
  std::printf("%s: wrote a %lld x %lld generated seafloor as patch %d (%d levels, %s) in %s\n", o.store.c_str(),
              o.width, o.height, r.patch_id, r.stats.levels, FormatBytes(double(r.stats.bytes)).c_str(),
              TimeRateMemory(seconds, double(o.width) * double(o.height)).c_str());
  std::printf("Look at it:\n"
              "  build/rolamos info %s\n"
              "  build/rolamos export %s --scale 0.0625 -o overview.jpg\n"
              "  build/rolamos export %s --region 8000,8000,1024,768 -o detail.png\n"
              "  gdalinfo %s   |   vips dzsave ... (any TIFF reader opens it)\n",
              o.store.c_str(), o.store.c_str(), o.store.c_str(), r.image_path.c_str());
  return 0;
}

void AddDemoCommand(CLI::App& app, Runner* run) {
  auto s = std::make_shared<DemoSwitches>();
  auto* cmd = app.add_subcommand(
      "demo", "Write a generated seafloor image into a new store (no download needed)");
  cmd->add_option("-o,--output", s->output, "store to create")->capture_default_str();
  cmd->add_option("--size", s->size, "side of the square image in pixels")->capture_default_str();
  AddTiffSwitches(cmd, &s->tiff);
  cmd->add_flag("-q,--quiet", s->quiet, "no progress bar");
  cmd->callback([s, run] { *run = [s] { return RunDemo(*s); }; });
}

}  // namespace rolamos::cli

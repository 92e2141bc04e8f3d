#include <cstdio>

#include "command.h"
#include "rolamos/convert.hpp"
#include "util/memory.h"
#include "util/progress.h"

namespace rolamos::cli {

struct ConvertSwitches {
  std::string input, output;
  TiffSwitches tiff;
  double cache_mb = ConvertOptions{}.cache_mb;
  bool quiet = false;
};

static int RunConvert(const ConvertSwitches& s) {
  ConvertOptions o;
  o.input = s.input;
  o.output = s.output;
  o.tiff = ToWriteOptions(s.tiff);
  o.cache_mb = s.cache_mb;
  Progress progress("convert", s.quiet);
  ConvertResult r = ConvertImage(o, [&](double f) { progress.Update(f); });
  progress.Done();
  const double seconds = progress.ElapsedSeconds();
  std::printf("%s: %lld x %lld, %d channels -> %s: %d levels, %lld tiles, %s, %s\n", o.input.c_str(), r.width,
              r.height, r.channels, o.output.c_str(), r.stats.levels, r.stats.tiles,
              FormatBytes(double(r.stats.bytes)).c_str(), TimeRateMemory(seconds, double(r.width) * double(r.height)).c_str());
  return 0;
}

void AddConvertCommand(CLI::App& app, Runner* run) {
  auto s = std::make_shared<ConvertSwitches>();
  auto* cmd = app.add_subcommand(
      "convert", "Any image OpenImageIO or GDAL reads -> pyramidal tiled BigTIFF (streamed)");
  cmd->add_option("input", s->input, "input image")->required();
  cmd->add_option("-o,--output", s->output, "output .tif")->required();
  AddTiffSwitches(cmd, &s->tiff);
  cmd->add_option("--cache-mb", s->cache_mb, "tile cache memory limit for reading, MB")
      ->capture_default_str();
  cmd->add_flag("-q,--quiet", s->quiet, "no progress bar");
  cmd->callback([s, run] { *run = [s] { return RunConvert(*s); }; });
}

}  // namespace rolamos::cli

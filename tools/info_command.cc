#include <iostream>

#include "command.h"
#include "rolamos/describe.hpp"
#include "rolamos/store.hpp"

namespace rolamos::cli {

struct InfoOptions {
  std::string path;
  bool json = false;
};

static int RunInfo(const InfoOptions& o) {
  const auto d = Store::LooksLikeStore(o.path) ? DescribeStore(o.path) : DescribeImage(o.path);
  if (o.json)
    std::cout << d.dump(2) << "\n";
  else
    std::cout << FormatDescription(d);
  // A store with a damaged patch is reported in full, and the exit code says so.
  if (d.contains("patches"))
    for (const auto& p : d["patches"])
      if (p.contains("problem")) return 1;
  if (d.contains("mosaic") && d["mosaic"].contains("problem")) return 1;
  return 0;
}

void AddInfoCommand(CLI::App& app, Runner* run) {
  auto o = std::make_shared<InfoOptions>();
  auto* cmd = app.add_subcommand("info", "Levels, tiles, codec, patches, global record, georeference");
  cmd->add_option("path", o->path, "a store directory or an image file")->required();
  cmd->add_flag("--json", o->json, "print JSON instead of text");
  cmd->callback([o, run] { *run = [o] { return RunInfo(*o); }; });
}

}  // namespace rolamos::cli

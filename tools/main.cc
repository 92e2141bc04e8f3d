// rolamos: one binary, one subcommand per job. Argument parsing only; the library does the work.
#include <malloc.h>

#include <cstdio>

#include "rolamos/error.hpp"
#include "rolamos/version.hpp"
#include "command.h"

int main(int argc, char** argv) {
  // Frames, warps and tiles are megabytes each, allocated and freed at every frame: keep them in
  // the heap instead of mapping and unmapping (and page-faulting) them each time.
  mallopt(M_MMAP_THRESHOLD, 64 << 20);
  mallopt(M_TRIM_THRESHOLD, 128 << 20);
  // Two heaps, not one per thread: the engine's threads (preparation, keyframe workers, patch
  // writer, OpenCV's) each keeping freed frames in an arena of its own cost ~150 MB of peak
  // memory on 1,000 frames of 800 x 600, for no measurable speed.
  mallopt(M_ARENA_MAX, 2);
  CLI::App app{"rolamos " ROLAMOS_VERSION_STRING
               ": seafloor maps from downward-looking underwater cameras"};
  app.set_version_flag("--version", "rolamos " ROLAMOS_VERSION_STRING);
  app.require_subcommand(1);
  rolamos::cli::Runner run;
  rolamos::cli::AddDemoCommand(app, &run);
  rolamos::cli::AddSynthCommand(app, &run);
  rolamos::cli::AddMosaicCommand(app, &run);
  rolamos::cli::AddComposeCommand(app, &run);
  rolamos::cli::AddAlignCommand(app, &run);
  rolamos::cli::AddMergeCommand(app, &run);
  rolamos::cli::AddServeCommand(app, &run);
  rolamos::cli::AddTilesCommand(app, &run);
  rolamos::cli::AddObjectsCommand(app, &run);
  rolamos::cli::AddConvertCommand(app, &run);
  rolamos::cli::AddInfoCommand(app, &run);
  rolamos::cli::AddExportCommand(app, &run);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // Help and version exit 0; any other usage error exits 2, whatever CLI11's own code.
    return app.exit(e) == 0 ? 0 : 2;
  }
  try {
    return run ? run() : 2;
  } catch (const rolamos::Error& e) {
    std::fprintf(stderr, "rolamos: error: %s\n", rolamos::cli::WithFlagHints(e.what()).c_str());
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "rolamos: internal error: %s\n", e.what());
    return 3;
  }
}

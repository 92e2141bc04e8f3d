// rolamos: one binary, one subcommand per job. Argument parsing only; the library does the work.
//
// This launcher runs `mosaic` itself and hands every other command to the full module
// (librolamos_full.so, beside it; cli_main.cc). The commands that read, serve and export maps
// need OpenImageIO, GDAL and OpenCV's codecs: ~280 shared libraries, 0.18 s to load at every
// start, 9 % of mapping 60 frames of 1292 x 964. The engine reads JPEG frames with libjpeg and
// writes patches with libtiff: the launcher is linked without them, and loads the module only when
// a run needs it (a video, frames that are not JPEG, a mask image, the viewer of --serve).
#include <malloc.h>

#include <cstdio>
#include <cstring>

#include "command.h"
#include "rolamos/error.hpp"
#include "util/full_module.h"

namespace {

// `--version` says what the module would say.
bool RunsHere(int argc, char** argv) {
  if (argc == 2 && std::strcmp(argv[1], "--version") == 0) return true;
  return argc >= 2 && std::strcmp(argv[1], "mosaic") == 0;
}

// `mosaic --serve`'s viewer, from the module (tools/mosaic_viewer.cc), loaded when a run serves.
std::shared_ptr<void> ViewerFromModule(rolamos::Store& store, const rolamos::cli::LiveViewerSwitches& viewer) {
  using Start = void (*)(rolamos::Store*, const rolamos::cli::LiveViewerSwitches*, std::shared_ptr<void>*);
  std::shared_ptr<void> handle;
  reinterpret_cast<Start>(rolamos::FullModuleSymbol("rolamos_start_live_viewer"))(&store, &viewer, &handle);
  return handle;
}

int RunFullModule(int argc, char** argv) {
  try {
    using Main = int (*)(int, char**);
    return reinterpret_cast<Main>(rolamos::FullModuleSymbol("rolamos_cli_main"))(argc, argv);
  } catch (const rolamos::Error& e) {
    std::fprintf(stderr, "rolamos: error: %s\n", e.what());
    return 1;
  }
}

}  // namespace

int main(int argc, char** argv) {
  // Frames, warps and tiles are megabytes each, allocated and freed at every frame: keep them in
  // the heap instead of mapping and unmapping (and page-faulting) them each time.
  mallopt(M_MMAP_THRESHOLD, 64 << 20);
  mallopt(M_TRIM_THRESHOLD, 128 << 20);
  // Two heaps, not one per thread: the engine's threads (preparation, keyframe workers, patch
  // writer, OpenCV's) each keeping freed frames in an arena of its own cost ~150 MB of peak
  // memory on 1,000 frames of 800 x 600, for no measurable speed.
  mallopt(M_ARENA_MAX, 2);
  if (!RunsHere(argc, argv)) return RunFullModule(argc, argv);
  const auto app = rolamos::cli::MakeApp();
  rolamos::cli::Runner run;
  rolamos::cli::AddMosaicCommand(*app, &run, &ViewerFromModule);
  return rolamos::cli::ParseAndRun(*app, run, argc, argv);
}

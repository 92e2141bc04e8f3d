// rolamos: one binary, one subcommand per job. Argument parsing only; the library does the work.
//
// This launcher runs `mosaic` itself and hands every other command to the full module
// (librolamos_full.so, beside it; cli_main.cc). The commands that read, serve and export maps
// need OpenImageIO, GDAL and OpenCV's codecs: ~280 shared libraries, 0.18 s to load at every
// start, 9 % of mapping 60 frames of 1292 x 964. The engine reads JPEG frames with libjpeg and
// writes patches with libtiff: the launcher is linked without them, and loads the module only when
// a run needs it (a video, frames that are not JPEG, a mask image, the viewer of --serve).
#include <cstdio>
#include <cstring>

#include "command.h"
#include "rolamos/error.hpp"
#include "util/full_module.h"
#include "util/heap_tuning.h"

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

// What reads a line or two of a store, and help, starts as it is: the restart costs ~30 ms.
bool AllocatesLittle(int argc, char** argv) {
  if (argc < 2 || std::strcmp(argv[1], "info") == 0) return true;
  for (int i = 1; i < argc; ++i)
    for (const char* quick : {"--version", "--help", "-h"})
      if (std::strcmp(argv[i], quick) == 0) return true;
  return false;
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
  // Megabytes allocated and freed at every frame: on huge pages, in one heap kept between frames
  // (util/heap_tuning.h says why and what it saves).
  if (!AllocatesLittle(argc, argv)) rolamos::RestartWithHugePageHeap(argv);
  rolamos::KeepOneHeap();
  if (!RunsHere(argc, argv)) return RunFullModule(argc, argv);
  const auto app = rolamos::cli::MakeApp();
  rolamos::cli::Runner run;
  rolamos::cli::AddMosaicCommand(*app, &run, &ViewerFromModule);
  return rolamos::cli::ParseAndRun(*app, run, argc, argv);
}

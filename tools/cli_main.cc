// Every subcommand: the full module's entry point (librolamos_full.so), which the launcher
// (main.cc) calls for all but its own `mosaic`.
#include "command.h"

extern "C" int rolamos_cli_main(int argc, char** argv) {
  using namespace rolamos::cli;
  const auto app = MakeApp();
  Runner run;
  AddDemoCommand(*app, &run);
  AddSynthCommand(*app, &run);
  AddMosaicCommand(*app, &run, &StartLiveViewer);
  AddComposeCommand(*app, &run);
  AddAlignCommand(*app, &run);
  AddMergeCommand(*app, &run);
  AddServeCommand(*app, &run);
  AddTilesCommand(*app, &run);
  AddObjectsCommand(*app, &run);
  AddConvertCommand(*app, &run);
  AddInfoCommand(*app, &run);
  AddExportCommand(*app, &run);
  return ParseAndRun(*app, run, argc, argv);
}

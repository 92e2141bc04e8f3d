// Each subcommand lives in its own file: it declares its switches into an Options struct,
// validates them, and calls one library function (as COLMAP's and PDAL's commands do).
#pragma once

#include <CLI/CLI.hpp>

#include <functional>
#include <memory>
#include <string>

#include "rolamos/image_format.hpp"
#include "rolamos/tiff_writer.hpp"

namespace rolamos {
class Store;
}

namespace rolamos::cli {

// Registers a subcommand; `run` is set to the function main() calls when it was chosen.
using Runner = std::function<int()>;
void AddConvertCommand(CLI::App& app, Runner* run);
void AddInfoCommand(CLI::App& app, Runner* run);
void AddExportCommand(CLI::App& app, Runner* run);
void AddDemoCommand(CLI::App& app, Runner* run);
void AddSynthCommand(CLI::App& app, Runner* run);
// `mosaic --live --serve`'s viewer: started by `start_viewer` (StartLiveViewer, in the full module
// only; the launcher reaches it through the module: main.cc); the handle it returns stops it when
// released.
struct LiveViewerSwitches {
  int port = -1;  // --serve (0: any free port; -1: no viewer)
  std::string bind = "127.0.0.1";
  std::string navigation, navigation_crs;  // georeference the live view
  double focal_px = 0;
};
using LiveViewerStarter = std::function<std::shared_ptr<void>(Store& store, const LiveViewerSwitches& viewer)>;
std::shared_ptr<void> StartLiveViewer(Store& store, const LiveViewerSwitches& viewer);
void AddMosaicCommand(CLI::App& app, Runner* run, LiveViewerStarter start_viewer);
void AddComposeCommand(CLI::App& app, Runner* run);
void AddServeCommand(CLI::App& app, Runner* run);
void AddTilesCommand(CLI::App& app, Runner* run);
void AddObjectsCommand(CLI::App& app, Runner* run);
void AddAlignCommand(CLI::App& app, Runner* run);
void AddMergeCommand(CLI::App& app, Runner* run);

// --compression/--quality/--tile shared by every command that writes a TIFF.
struct TiffSwitches {
  std::string compression = "jpeg";
  int quality = 90;
  int tile = 256;
  int threads = 0;
  int zstd_level = 9;
  int webp_method = 4;
};
void AddTiffSwitches(CLI::App* cmd, TiffSwitches* s);
// Throws rolamos::Error for an unknown codec name.
TiffWriteOptions ToWriteOptions(const TiffSwitches& s);
// The switches' defaults from a library default (e.g. MosaickerOptions::PatchWriteOptions()).
TiffSwitches FromWriteOptions(const TiffWriteOptions& o);

// "x,y,w,h" -> four numbers; throws rolamos::Error naming the text.
std::array<double, 4> ParseRegion(const std::string& text);

// The application every entry point parses with (its name, description and --version).
std::unique_ptr<CLI::App> MakeApp();
// Parses argv and runs the subcommand chosen; reports errors as the CLI does. The exit code.
int ParseAndRun(CLI::App& app, const Runner& run, int argc, char** argv);

// A library error as the user of the CLI reads it: the library names values and options
// ("max_pixels", "their CRS must be given"); this adds the flag that sets them.
std::string WithFlagHints(const std::string& message);

// The end of a one-line summary: "12.3 s (45.6 Mpx/s), peak memory 789 MiB".
std::string TimeRateMemory(double seconds, double pixels);

// Human-readable sizes for summaries.
std::string FormatBytes(double bytes);

}  // namespace rolamos::cli

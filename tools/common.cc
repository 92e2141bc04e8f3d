#include <algorithm>
#include <cstdio>
#include <sstream>

#include "command.h"
#include "rolamos/error.hpp"
#include "rolamos/version.hpp"
#include "util/memory.h"

namespace rolamos::cli {

std::unique_ptr<CLI::App> MakeApp() {
  auto app = std::make_unique<CLI::App>("rolamos " ROLAMOS_VERSION_STRING
                                        ": seafloor maps from downward-looking underwater cameras");
  app->set_version_flag("--version", "rolamos " ROLAMOS_VERSION_STRING);
  app->require_subcommand(1);
  return app;
}

int ParseAndRun(CLI::App& app, const Runner& run, int argc, char** argv) {
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // Help and version exit 0; any other usage error exits 2, whatever CLI11's own code.
    return app.exit(e) == 0 ? 0 : 2;
  }
  try {
    return run ? run() : 2;
  } catch (const Error& e) {
    std::fprintf(stderr, "rolamos: error: %s\n", WithFlagHints(e.what()).c_str());
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "rolamos: internal error: %s\n", e.what());
    return 3;
  }
}

void AddTiffSwitches(CLI::App* cmd, TiffSwitches* s) {
  cmd->add_option("--compression", s->compression, "none, jpeg, jpeg-mask (JPEG, alpha as a 1-bit mask), deflate, zstd or webp")
      ->capture_default_str();
  cmd->add_option("--quality", s->quality, "JPEG/WebP quality 1..100")->capture_default_str();
  cmd->add_option("--tile", s->tile, "tile size, 256 or 512")->capture_default_str();
  cmd->add_option("--threads", s->threads, "compression threads (0 = one per core)")
      ->capture_default_str();
  cmd->add_option("--zstd-level", s->zstd_level, "zstd level 1..22 (higher: smaller, slower)")
      ->capture_default_str();
  cmd->add_option("--webp-method", s->webp_method,
                  "WebP effort 0..6 (like cwebp -m; lower: faster, slightly lower fidelity)")
      ->capture_default_str();
}

TiffWriteOptions ToWriteOptions(const TiffSwitches& s) {
  TiffWriteOptions o;
  if (!ParseCompression(s.compression, &o.compression)) {
    std::string names;
    for (const auto& n : CompressionNames()) names += (names.empty() ? "" : ", ") + n;
    Fail("--compression", "unknown codec \"" + s.compression + "\" (choose one of " + names + ")");
  }
  o.quality = s.quality;
  o.tile_size = s.tile;
  o.threads = s.threads;
  o.zstd_level = s.zstd_level;
  o.webp_method = s.webp_method;
  return o;
}

TiffSwitches FromWriteOptions(const TiffWriteOptions& o) {
  TiffSwitches s;
  s.compression = CompressionName(o.compression);
  s.quality = o.quality;
  s.tile = o.tile_size;
  s.threads = o.threads;
  s.zstd_level = o.zstd_level;
  s.webp_method = o.webp_method;
  return s;
}

std::array<double, 4> ParseRegion(const std::string& text) {
  std::array<double, 4> v{};
  std::stringstream ss(text);
  std::string part;
  int i = 0;
  while (std::getline(ss, part, ',')) {
    if (i >= 4) Fail("--region " + text, "expected x,y,w,h (four numbers)");
    try {
      size_t used = 0;
      v[static_cast<size_t>(i)] = std::stod(part, &used);
      if (used != part.size()) throw std::invalid_argument(part);
    } catch (const std::exception&) {
      Fail("--region " + text, "\"" + part + "\" is not a number");
    }
    ++i;
  }
  if (i != 4) Fail("--region " + text, "expected x,y,w,h (four numbers)");
  if (v[2] <= 0 || v[3] <= 0) Fail("--region " + text, "width and height must be positive");
  return v;
}

std::string FormatBytes(double bytes) {
  const char* units[] = {"B", "KiB", "MiB", "GiB", "TiB"};
  int u = 0;
  while (bytes >= 1024 && u < 4) {
    bytes /= 1024;
    ++u;
  }
  char buf[32];
  std::snprintf(buf, sizeof buf, u == 0 ? "%.0f %s" : "%.1f %s", bytes, units[u]);
  return buf;
}

std::string WithFlagHints(const std::string& message) {
  static const std::pair<const char*, const char*> kHints[] = {
      {"their CRS must be given", "--crs EPSG:XXXX"},
      {"focal length in pixels is needed", "--focal"},
      {"max_pixels", "--max-pixels"},
      {"compose again from the start (restart)", "--restart"},
      {"frames_dir", "--frames DIR"},
      {"or choose a patch", "--patch N"},
      {"choose a smaller scale", "--scale"},
      {"lower the ground sample distance", "--gsd"},
      {"encoding \"fisher\"", "--encoding fisher"},
      {"encoding \"bow\"", "--encoding bow"},
  };
  std::string hints;
  for (const auto& [phrase, flag] : kHints)
    if (message.find(phrase) != std::string::npos) hints += std::string(hints.empty() ? "" : ", ") + flag;
  return hints.empty() ? message : message + " [" + hints + "]";
}

std::string TimeRateMemory(double seconds, double pixels) {
  char b[128];
  std::snprintf(b, sizeof b, "%.1f s (%.1f Mpx/s), peak memory %.0f MiB", seconds,
                pixels / 1e6 / std::max(seconds, 1e-9), PeakRssMb());
  return b;
}

}  // namespace rolamos::cli

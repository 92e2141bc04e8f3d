// Synthetic stores for the compose scale figures, driven by bench/run_compose_scale.py:
//   compose_scale_bench make  --width W --height H --patch P --overlap O -o STORE [--georef]
//       a grid of P x P patches, each slightly rotated and scaled, cut from a periodic
//       procedural seafloor so that overlaps agree; with --georef every patch TIFF also carries
//       its placement as a geotransform (for gdalwarp, the peer).
//   compose_scale_bench check --store STORE [--samples N]
//       compares random windows of the composed mosaic.tif with the seafloor they should show.
// Each prints one JSON line.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <random>
#include <string>

#include <opencv2/imgproc.hpp>

#include "rolamos/store.hpp"
#include "rolamos/tiff_writer.hpp"
#include "rolamos/tiled_image.hpp"
#include "synth/seafloor_texture.h"
#include "util/homography.h"

using namespace rolamos;
using Clock = std::chrono::steady_clock;

namespace {

constexpr int kPeriod = 8192;  // the seafloor repeats every kPeriod pixels

std::string Arg(int argc, char** argv, const std::string& name, const std::string& def = "") {
  for (int i = 2; i + 1 < argc; ++i)
    if (argv[i] == name) return argv[i + 1];
  return def;
}

bool Flag(int argc, char** argv, const std::string& name) {
  for (int i = 2; i < argc; ++i)
    if (argv[i] == name) return true;
  return false;
}

cv::Mat Texture() {
  return RenderSeafloor(0, 0, kPeriod, kPeriod);
}

// OpenCV's warps address the source with 16-bit integers: source coordinates past 32767 come out
// wrong. The seafloor repeats every kPeriod pixels, so whole periods are taken off first.
cv::Matx33d WrapTranslation(cv::Matx33d M) {
  M(0, 2) -= kPeriod * std::floor(M(0, 2) / kPeriod);
  M(1, 2) -= kPeriod * std::floor(M(1, 2) / kPeriod);
  return M;
}

int Make(long long width, long long height, int patch, int overlap, const std::string& out, bool georef) {
  const auto t0 = Clock::now();
  const cv::Mat texture = Texture();
  Store store = Store::Create(out);
  const int step = patch - overlap;
  const long long nx = std::max(1LL, (width - overlap + step - 1) / step);
  const long long ny = std::max(1LL, (height - overlap + step - 1) / step);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> angle(-0.004, 0.004), zoom(0.995, 1.005);
  long long pixels = 0;
  for (long long j = 0; j < ny; ++j) {
    for (long long i = 0; i < nx; ++i) {
      // patch pixel -> global pixel: a small rotation and scale about the patch centre.
      const double a = angle(rng), s = zoom(rng), c = patch / 2.0;
      const cv::Matx33d rot(s * std::cos(a), -s * std::sin(a), 0, s * std::sin(a), s * std::cos(a), 0, 0, 0, 1);
      const cv::Matx33d G = cv::Matx33d(1, 0, i * step + c, 0, 1, j * step + c, 0, 0, 1) * rot *
                            cv::Matx33d(1, 0, -c, 0, 1, -c, 0, 0, 1);
      PixelLayout layout;
      layout.width = layout.height = patch;
      layout.channels = 3;
      TiffWriteOptions o;  // JPEG q90, as a camera survey's patches might be
      const int id = store.NextPatchId();
      PyramidTiffWriter writer(store.PatchImagePath(id), layout, o);
      if (georef) {
        Georef g;
        g.crs = "EPSG:32755";
        g.geotransform = {G(0, 2), G(0, 0), G(0, 1), G(1, 2), G(1, 0), G(1, 1)};
        writer.SetGeoref(g);
      }
      for (int y = 0; y < patch; y += writer.band_height()) {
        const int rows = std::min(writer.band_height(), patch - y);
        // band pixel -> global pixel (= texture pixel, wrapped)
        const cv::Matx33d M = WrapTranslation(G * cv::Matx33d(1, 0, 0, 0, 1, y, 0, 0, 1));
        cv::Mat band;
        cv::warpPerspective(texture, band, cv::Mat(M), cv::Size(patch, rows),
                            cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_WRAP);
        writer.WriteBand(band);
      }
      writer.Finish();
      PatchSidecar sc;
      sc.id = id;
      sc.size = {patch, patch};
      sc.n_images = 1;
      sc.patch_to_global = ToArray9(G);
      sc.extra["synthetic_to_global"] = ToArray9(G);
      store.CommitPatch(sc);
      pixels += 1LL * patch * patch;
      std::fprintf(stderr, "\rpatch %lld/%lld", j * nx + i + 1, nx * ny);
    }
  }
  std::fprintf(stderr, "\n");
  std::printf("{\"patches\": %lld, \"patch_gigapixels\": %.2f, \"seconds\": %.1f}\n", nx * ny, pixels / 1e9,
              std::chrono::duration<double>(Clock::now() - t0).count());
  return 0;
}

int Check(const std::string& dir, int samples) {
  Store store = Store::Open(dir);
  const PatchSidecar first = store.ReadSidecar(store.patches().front().id);
  // compose stored O * G; the mosaic's origin in global pixels is O's translation.
  const cv::Matx33d O = ToMatx(*first.patch_to_global) * ToMatx(first.extra["synthetic_to_global"].get<Homography>()).inv();
  const cv::Mat texture = Texture();
  TiledImage mosaic = TiledImage::Open(store.MosaicPath(), std::make_shared<TileCache>());
  std::mt19937 rng(3);
  double sum = 0;
  long long n = 0;
  int windows = 0;
  for (int k = 0; k < samples * 20 && windows < samples; ++k) {
    const int w = 256;
    const int x = std::uniform_int_distribution<int>(0, static_cast<int>(mosaic.width() - w))(rng);
    const int y = std::uniform_int_distribution<int>(0, static_cast<int>(mosaic.height() - w))(rng);
    cv::Mat got = mosaic.ReadRegion(0, cv::Rect(x, y, w, w));
    std::vector<cv::Mat> ch;
    cv::split(got, ch);
    if (cv::countNonZero(ch[3] == 255) < w * w) continue;  // only windows fully inside the data
    // mosaic pixel -> global pixel = texture pixel (wrapped)
    const cv::Matx33d M = WrapTranslation(O.inv() * cv::Matx33d(1, 0, x, 0, 1, y, 0, 0, 1));
    cv::Mat want;
    cv::warpPerspective(texture, want, cv::Mat(M), cv::Size(w, w), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_WRAP);
    cv::Mat bgr;
    cv::cvtColor(got, bgr, cv::COLOR_BGRA2BGR);
    cv::Mat diff;
    cv::absdiff(bgr, want, diff);
    const double window_sum = cv::sum(diff)[0] + cv::sum(diff)[1] + cv::sum(diff)[2];
    if (std::getenv("CHECK_VERBOSE")) std::fprintf(stderr, "window %d %d: %.2f\n", x, y, window_sum / (3.0 * w * w));
    sum += window_sum;
    n += 3LL * w * w;
    ++windows;
  }
  std::printf("{\"windows\": %d, \"mean_abs_diff\": %.3f, \"width\": %lld, \"height\": %lld}\n", windows,
              n ? sum / n : -1.0, mosaic.width(), mosaic.height());
  return windows > 0 ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  const std::string cmd = argc > 1 ? argv[1] : "";
  try {
    if (cmd == "make")
      return Make(std::stoll(Arg(argc, argv, "--width", "20000")), std::stoll(Arg(argc, argv, "--height", "10000")),
                  std::stoi(Arg(argc, argv, "--patch", "4096")), std::stoi(Arg(argc, argv, "--overlap", "512")),
                  Arg(argc, argv, "-o"), Flag(argc, argv, "--georef"));
    if (cmd == "check") return Check(Arg(argc, argv, "--store"), std::stoi(Arg(argc, argv, "--samples", "40")));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 1;
  }
  std::fprintf(stderr, "usage: compose_scale_bench make|check ...\n");
  return 2;
}

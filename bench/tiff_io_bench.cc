// Benchmarks of the store's TIFF I/O, driven by bench/run_tiff_io.sh (which also runs the peers):
//   tiff_io_bench make-raw  --size N -o FILE      procedural seafloor as raw RGB, streamed
//   tiff_io_bench write     --raw FILE --size N -o OUT.tif [--compression C] [--quality Q]
//   tiff_io_bench read      --tif FILE [--samples N] [--cache-mb MB]
// Each prints one JSON line of figures.
#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "rolamos/tiff_writer.hpp"
#include "rolamos/tiled_image.hpp"
#include "synth/seafloor_texture.h"
#include "util/memory.h"

using namespace rolamos;
using Clock = std::chrono::steady_clock;

namespace {

std::string Arg(int argc, char** argv, const std::string& name, const std::string& def = "") {
  for (int i = 2; i + 1 < argc; ++i)
    if (argv[i] == name) return argv[i + 1];
  return def;
}

double Seconds(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

int MakeRaw(long long size, const std::string& out) {
  FILE* f = std::fopen(out.c_str(), "wb");
  if (!f) return 1;
  for (long long y = 0; y < size; y += 256) {
    const int rows = static_cast<int>(std::min<long long>(256, size - y));
    cv::Mat band = RenderSeafloor(0, y, static_cast<int>(size), rows);
    cv::cvtColor(band, band, cv::COLOR_BGR2RGB);  // raw files are RGB, as vips reads them
    std::fwrite(band.data, 1, band.total() * 3, f);
  }
  std::fclose(f);
  std::printf("{\"raw\": \"%s\", \"size\": %lld}\n", out.c_str(), size);
  return 0;
}

int Write(const std::string& raw, long long size, const std::string& out, Compression c,
          int quality) {
  int fd = ::open(raw.c_str(), O_RDONLY);
  if (fd < 0) return 1;
  auto t0 = Clock::now();
  PixelLayout layout;
  layout.width = layout.height = size;
  TiffWriteOptions o;
  o.compression = c;
  o.quality = quality;
  PyramidTiffWriter writer(out, layout, o);
  cv::Mat rgb(256, static_cast<int>(size), CV_8UC3);
  for (long long y = 0; y < size; y += 256) {
    const int rows = static_cast<int>(std::min<long long>(256, size - y));
    const size_t bytes = size_t(rows) * size_t(size) * 3;
    if (::pread(fd, rgb.data, bytes, static_cast<off_t>(y * size * 3)) != static_cast<ssize_t>(bytes))
      return 1;
    cv::Mat band = rgb.rowRange(0, rows);
    cv::cvtColor(band, band, cv::COLOR_RGB2BGR);
    writer.WriteBand(band);
  }
  auto stats = writer.Finish();
  ::close(fd);
  std::printf("{\"seconds\": %.3f, \"peak_rss_mb\": %.1f, \"bytes\": %lld, \"levels\": %d}\n",
              Seconds(t0), PeakRssMb(), stats.bytes, stats.levels);
  return 0;
}

int Read(const std::string& tif, int samples, double cache_mb) {
  TileCacheOptions co;
  co.max_memory_mb = cache_mb;
  auto cache = std::make_shared<TileCache>(co);
  TiledImage image = TiledImage::Open(tif, cache);
  const double baseline_mb = CurrentRssMb();  // libraries loaded, nothing cached yet
  std::mt19937 rng(42);
  auto random_rects = [&](long long span_w, long long span_h, int n) {
    std::vector<cv::Rect> rects;
    std::uniform_int_distribution<long long> dx(0, span_w - 256), dy(0, span_h - 256);
    for (int i = 0; i < n; ++i)
      rects.emplace_back(static_cast<int>(dx(rng)), static_cast<int>(dy(rng)), 256, 256);
    return rects;
  };
  auto time_reads = [&](const std::vector<cv::Rect>& rects) {
    std::vector<double> ms;
    for (const auto& r : rects) {
      auto t0 = Clock::now();
      cv::Mat m = image.ReadRegion(0, r);
      ms.push_back(Seconds(t0) * 1e3);
    }
    std::sort(ms.begin(), ms.end());
    return ms;
  };
  // Cold: random places over the whole image (mostly tile-cache misses: decode from the file).
  auto cold = time_reads(random_rects(image.width(), image.height(), samples));
  // Warm: random places inside an area whose tiles fit the cache, read once to warm it.
  const long long side = std::min<long long>(image.width(), 4096);
  auto warm_rects = random_rects(side, side, samples);
  time_reads(warm_rects);
  auto warm = time_reads(warm_rects);
  auto pct = [](const std::vector<double>& v, double p) {
    return v[std::min(v.size() - 1, static_cast<size_t>(p * v.size()))];
  };
  std::printf("{\"cold_median_ms\": %.3f, \"cold_p99_ms\": %.3f, \"warm_median_ms\": %.3f, "
              "\"warm_p99_ms\": %.3f, \"cache_mb\": %.0f, \"peak_rss_mb\": %.1f, "
              "\"baseline_rss_mb\": %.1f, \"growth_mb\": %.1f}\n",
              pct(cold, 0.5), pct(cold, 0.99), pct(warm, 0.5), pct(warm, 0.99), cache_mb,
              PeakRssMb(), baseline_mb, PeakRssMb() - baseline_mb);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: tiff_io_bench make-raw|write|read ...\n");
    return 2;
  }
  const std::string mode = argv[1];
  const long long size = std::stoll(Arg(argc, argv, "--size", "32768"));
  if (mode == "make-raw") return MakeRaw(size, Arg(argc, argv, "-o"));
  if (mode == "write") {
    Compression c = Compression::kJpeg;
    ParseCompression(Arg(argc, argv, "--compression", "jpeg"), &c);
    return Write(Arg(argc, argv, "--raw"), size, Arg(argc, argv, "-o"), c,
                 std::stoi(Arg(argc, argv, "--quality", "90")));
  }
  if (mode == "read")
    return Read(Arg(argc, argv, "--tif"), std::stoi(Arg(argc, argv, "--samples", "2000")),
                std::stod(Arg(argc, argv, "--cache-mb", "256")));
  std::fprintf(stderr, "unknown mode %s\n", mode.c_str());
  return 2;
}

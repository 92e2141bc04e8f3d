#include "test_support.h"

#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>

#include <map>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/compose.hpp"
#include "rolamos/error.hpp"
#include "rolamos/mosaicker.hpp"
#include "synth/seafloor_texture.h"
#include "util/homography.h"

namespace fs = std::filesystem;

namespace rolamos::test {

ScratchDir::ScratchDir() {
  static std::atomic<int> counter{0};
  fs::path base = fs::temp_directory_path() / "rolamos-tests";
  fs::create_directories(base);
  path_ = (base / (std::to_string(getpid()) + "-" + std::to_string(counter++))).string();
  fs::remove_all(path_);
  fs::create_directories(path_);
}

ScratchDir::~ScratchDir() {
  std::error_code ec;
  fs::remove_all(path_, ec);
}

void TwoFeatureViews(const cv::Matx33d& a_to_b, cv::Size size, Features* a, Features* b) {
  cv::RNG rng(7);
  auto descriptor = [&](cv::Mat row) { rng.fill(row, cv::RNG::UNIFORM, 0, 120); };
  std::vector<cv::Mat> da, db;
  for (int i = 0; i < 600; ++i) {
    const cv::Point2f p(rng.uniform(0.f, size.width - 1.f), rng.uniform(0.f, size.height - 1.f));
    const cv::Vec3d q = a_to_b * cv::Vec3d(p.x, p.y, 1);
    const cv::Point2f in_b(float(q[0] / q[2]) + rng.uniform(-0.1f, 0.1f), float(q[1] / q[2]) + rng.uniform(-0.1f, 0.1f));
    cv::Mat d(1, 128, CV_32F);
    descriptor(d);
    a->points.push_back(p);
    da.push_back(d);
    if (in_b.x >= 0 && in_b.y >= 0 && in_b.x < size.width && in_b.y < size.height) {
      cv::Mat noisy = d.clone();
      for (int k = 0; k < 128; k += 16) noisy.at<float>(0, k) += 3;
      b->points.push_back(in_b);
      db.push_back(noisy);
    }
    cv::Mat own(1, 128, CV_32F);
    descriptor(own);
    b->points.emplace_back(rng.uniform(0.f, size.width - 1.f), rng.uniform(0.f, size.height - 1.f));
    db.push_back(own);
  }
  cv::vconcat(da, a->descriptors);
  cv::vconcat(db, b->descriptors);
}

cv::Mat MakeImage(int width, int height, int channels, int bits, uint32_t seed) {
  SeafloorTextureOptions o;
  o.seed = seed;
  cv::Mat bgr = RenderSeafloor(0, 0, width, height, o);
  cv::Mat out;
  if (channels == 1 || channels == 2) {
    cv::cvtColor(bgr, out, cv::COLOR_BGR2GRAY);
  } else {
    out = bgr;
  }
  if (channels == 2 || channels == 4) {
    // Alpha: an opaque ellipse in a transparent frame, like a patch of a mosaic.
    cv::Mat alpha = cv::Mat::zeros(height, width, CV_8U);
    cv::ellipse(alpha, cv::Point(width / 2, height / 2), cv::Size(width * 2 / 5, height * 2 / 5),
                15, 0, 360, cv::Scalar(255), cv::FILLED);
    std::vector<cv::Mat> ch;
    cv::split(out, ch);
    for (auto& c : ch) c.setTo(0, alpha == 0);
    ch.push_back(alpha);
    cv::merge(ch, out);
  }
  if (bits == 16) out.convertTo(out, CV_16U, 257.0);
  return out;
}

CommandResult RunShell(const std::string& command) {
  CommandResult r;
  FILE* pipe = popen((command + " 2>&1").c_str(), "r");
  if (!pipe) return r;
  std::array<char, 4096> buf;
  size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), pipe)) > 0) r.output.append(buf.data(), n);
  int status = pclose(pipe);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  return r;
}

CommandResult RunCli(const std::string& args) {
  return RunShell(std::string(ROLAMOS_CLI) + " " + args);
}

bool HaveCommand(const std::string& name) {
  return RunShell("command -v " + name + " >/dev/null").exit_code == 0;
}

std::string SharedData() {
  const char* env = std::getenv("ROLAMOS_SHARED_DATA");
  std::string dir = env ? env : std::string(ROLAMOS_SOURCE_DIR) + "/../shared/data";
  return fs::is_directory(dir) ? dir : "";
}

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

double MaskedPsnr(const cv::Mat& a, const cv::Mat& b) {
  const int cn = b.channels();
  cv::Mat alpha;
  cv::extractChannel(b, alpha, cn - 1);
  cv::Mat mask = alpha > 0;
  double sse = 0;
  long long n = 0;
  for (int c = 0; c < cn - 1; ++c) {
    cv::Mat ca, cb, d;
    cv::extractChannel(a, ca, c);
    cv::extractChannel(b, cb, c);
    ca.convertTo(ca, CV_64F);
    cb.convertTo(cb, CV_64F);
    d = ca - cb;
    d = d.mul(d);
    sse += cv::sum(d.setTo(0, ~mask))[0];
    n += cv::countNonZero(mask);
  }
  const double peak = b.depth() == CV_16U ? 65535.0 : 255.0;
  return n == 0 || sse == 0 ? 999.0 : 10 * std::log10(peak * peak / (sse / n));
}

double Psnr(const cv::Mat& a, const cv::Mat& b) { return cv::PSNR(a, b, a.depth() == CV_16U ? 65535 : 255); }

double PsnrAfterColourFit(const cv::Mat& a, const cv::Mat& b) {
  std::vector<cv::Mat> ac, bc;
  cv::split(a, ac);
  cv::split(b, bc);
  std::vector<cv::Mat> fitted;
  for (size_t c = 0; c < ac.size(); ++c) {
    cv::Mat x, y;
    ac[c].convertTo(x, CV_64F);
    bc[c].convertTo(y, CV_64F);
    cv::Scalar mx, sx, my, sy;
    cv::meanStdDev(x, mx, sx);
    cv::meanStdDev(y, my, sy);
    const double cov = cv::mean((x - mx[0]).mul(y - my[0]))[0];
    const double gain = sx[0] > 0 ? cov / (sx[0] * sx[0]) : 1.0;
    cv::Mat f = (x - mx[0]) * gain + my[0];
    f.convertTo(f, b.depth());
    fitted.push_back(f);
  }
  cv::Mat merged;
  cv::merge(fitted, merged);
  return Psnr(merged, b);
}

cv::Mat ShapeSample(const std::string& cls, uint32_t seed) {
  cv::RNG rng(seed);
  cv::Mat img = RenderSeafloor(rng.uniform(0, 50000), rng.uniform(0, 50000), 160, 160);
  const cv::Point2f c(80 + rng.uniform(-12.f, 12.f), 80 + rng.uniform(-12.f, 12.f));
  const float s = rng.uniform(0.8f, 1.25f), a = rng.uniform(0.f, static_cast<float>(CV_PI));
  const cv::Point2f u(std::cos(a), std::sin(a)), v(-std::sin(a), std::cos(a));
  if (cls == "disc") {
    cv::ellipse(img, cv::RotatedRect(c, cv::Size2f(44 * s, 34 * s), a * 57.3f), cv::Scalar(150, 60, 120), cv::FILLED, cv::LINE_AA);
  } else if (cls == "star") {
    for (int k = 0; k < 9; ++k) {
      const float t = a + k * static_cast<float>(CV_PI) / 4.5f;
      cv::line(img, c, c + 30 * s * cv::Point2f(std::cos(t), std::sin(t)), cv::Scalar(225, 230, 235), 2, cv::LINE_AA);
    }
  } else if (cls == "bar") {
    cv::line(img, c - 40 * s * u, c + 40 * s * u, cv::Scalar(30, 40, 35), static_cast<int>(7 * s), cv::LINE_AA);
    cv::circle(img, c + 40 * s * u + 3 * s * v, static_cast<int>(5 * s), cv::Scalar(30, 40, 35), cv::FILLED, cv::LINE_AA);
  }
  return img;
}

void WriteShapesDataset(const std::string& dir, int per_class, uint32_t seed, bool background) {
  std::vector<std::string> classes = kShapeClasses;
  if (background) classes.push_back("background");
  for (size_t c = 0; c < classes.size(); ++c) {
    std::filesystem::create_directories(dir + "/" + classes[c]);
    for (int i = 0; i < per_class; ++i) {
      char name[32];
      std::snprintf(name, sizeof name, "/%03d.png", i);
      cv::imwrite(dir + "/" + classes[c] + name, ShapeSample(classes[c], seed * 7919u + static_cast<uint32_t>(c * 1000 + i)));
    }
  }
}

SurveyOptions SmallSurvey(int frames) {
  SurveyOptions o;
  o.frame_width = 480;
  o.frame_height = 360;
  o.focal_px = 420;
  o.frames = frames;
  return o;
}

Store MosaicAndCompose(const std::string& frames_dir, const std::string& store_dir, double patch_megapixels) {
  MosaickerOptions mo;
  mo.tiff.compression = Compression::kZstd;
  if (patch_megapixels > 0) mo.patch_megapixels = patch_megapixels;
  Store store = Store::Create(store_dir);
  MosaicInput(frames_dir, store, mo);
  ComposeOptions co;
  co.tiff.compression = Compression::kZstd;
  ComposeMosaic(store, co);
  return store;
}

std::vector<double> ErrorsAgainstTruth(const Store& store, const Survey& truth, bool aligned) {
  std::map<std::string, cv::Matx33d> gt;
  for (const auto& f : truth.frames) gt[std::filesystem::path(f.file).filename().string()] = ToMatx(f.frame_to_world);
  std::vector<cv::Point2d> ours, theirs;
  for (const auto& p : store.patches()) {
    const PatchSidecar s = store.ReadSidecar(p.id);
    const Homography online = s.patch_to_global_online.value_or(*s.patch_to_global);
    for (const auto& f : s.frames) {
      const cv::Matx33d H = aligned ? ToMatx(f.frame_to_global.value())
                                    : ToMatx(online) * ToMatx(f.frame_to_patch);
      const cv::Matx33d T = gt.at(std::filesystem::path(f.source).filename().string());
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
          const cv::Point2d q(i * (truth.frame_size.width - 1) / 2.0, j * (truth.frame_size.height - 1) / 2.0);
          ours.push_back(ApplyHomography(H, q));
          theirs.push_back(ApplyHomography(T, q));
        }
    }
  }
  const cv::Mat fit = cv::findHomography(ours, theirs, 0);
  std::vector<cv::Point2d> mapped;
  cv::perspectiveTransform(ours, mapped, fit);
  std::vector<double> errors;
  for (size_t i = 0; i < mapped.size(); ++i) errors.push_back(cv::norm(mapped[i] - theirs[i]));
  return errors;
}

double Rms(const std::vector<double>& errors) {
  double sse = 0;
  for (double e : errors) sse += e * e;
  return errors.empty() ? 0 : std::sqrt(sse / errors.size());
}

void WriteSurveyNavigation(const Survey& s, const std::string& path, double focal, bool latlon) {
  std::ofstream out(path);
  out << (latlon ? "frame,lat,lon,altitude,heading\n" : "frame,easting,northing,epsg,altitude,heading\n");
  out.precision(12);
  for (const auto& f : s.frames) {
    const cv::Matx33d H = ToMatx(f.frame_to_world);
    const double cx = (s.frame_size.width - 1) / 2.0, cy = (s.frame_size.height - 1) / 2.0;
    auto world = [&](double x, double y) {
      const cv::Vec3d w = H * cv::Vec3d(x, y, 1);
      return cv::Point2d(500000 + 0.01 * w[0] / w[2], 5200000 - 0.01 * w[1] / w[2]);
    };
    const cv::Point2d c = world(cx, cy), up = world(cx, cy - 1), right = world(cx + 1, cy);
    const double heading = std::atan2(up.x - c.x, up.y - c.y) * 180 / CV_PI;
    const double gsd = cv::norm(right - c);
    out << fs::path(f.file).filename().string() << ",";
    if (latlon) {
      // Inverse UTM is not at hand in the test: a survey near the central meridian of zone 55
      // (147 E) at 43.5 S, with small offsets mapped by the local scale (metres per degree).
      const double lat = -43.5 + (c.y - 5200000) / 111120.0, lon = 147.0 + (c.x - 500000) / (111320.0 * std::cos(43.5 * CV_PI / 180));
      out << lat << "," << lon;
    } else {
      out << c.x << "," << c.y << ",32755";
    }
    out << "," << gsd * focal << "," << heading << "\n";
  }
}


// A burrow as the survey frames show one: a dark opening with a paler rim of spoil, on seafloor
// texture; returns its box.
static cv::Rect2d PlantBurrow(cv::Mat* bgr, cv::Point2d centre, double radius, std::mt19937* rng) {
  const double aspect = std::uniform_real_distribution<double>(0.8, 1.25)(*rng);
  const double rx = radius * aspect, ry = radius / aspect;
  for (int y = std::max(0, int(centre.y - ry * 1.5)); y < std::min(bgr->rows, int(centre.y + ry * 1.5)); ++y)
    for (int x = std::max(0, int(centre.x - rx * 1.5)); x < std::min(bgr->cols, int(centre.x + rx * 1.5)); ++x) {
      const double d = std::hypot((x - centre.x) / rx, (y - centre.y) / ry);
      // Dark inside (0.45 of the ground), a pale rim at the edge, fading out beyond it.
      double f = 1.0;
      if (d < 0.6) f = 0.45 + 0.2 * d;
      else if (d < 1.0) f = 0.57 + 0.9 * (d - 0.6) * 1.6;
      else if (d < 1.3) f = 1.15 - 0.5 * (d - 1.0);
      cv::Vec3b& p = bgr->at<cv::Vec3b>(y, x);
      for (int k = 0; k < 3; ++k) p[k] = cv::saturate_cast<uchar>(p[k] * f);
    }
  return {centre.x - rx, centre.y - ry, 2 * rx, 2 * ry};
}

// A survey frame: seafloor, burrows of 24..80 pixels, vignetting and a light cone, two laser
// dots and a burned-in timestamp (which are not burrows).
cv::Mat BurrowFrame(int index, std::vector<cv::Rect2d>* boxes, int width, int height) {
  std::mt19937 rng(1000 + index);
  cv::Mat bgr = RenderSeafloor(9000 + index * 1500, 5000, width, height);
  cv::Mat gray;
  cv::cvtColor(bgr, gray, cv::COLOR_BGR2GRAY);
  cv::cvtColor(gray, bgr, cv::COLOR_GRAY2BGR);  // the survey frames are nearly colourless
  boxes->clear();
  for (int k = 0, tries = 0; k < 10 && tries < 200; ++tries) {
    const double r = std::uniform_real_distribution<double>(12, 40)(rng);
    const cv::Point2d c(std::uniform_real_distribution<double>(r, width - r)(rng),
                        std::uniform_real_distribution<double>(r + 20, height - r)(rng));
    bool apart = true;
    for (const auto& b : *boxes)
      if (std::hypot(b.x + b.width / 2 - c.x, b.y + b.height / 2 - c.y) < r + b.width / 2 + 12) apart = false;
    if (!apart) continue;
    boxes->push_back(PlantBurrow(&bgr, c, r, &rng));
    ++k;
  }
  // Vignetting and a light cone off centre.
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      const double d = std::hypot(x - width * 0.6, y - height * 0.45) / std::hypot(width, height);
      const double f = 1.3 - 1.6 * d * d;
      cv::Vec3b& p = bgr.at<cv::Vec3b>(y, x);
      for (int q = 0; q < 3; ++q) p[q] = cv::saturate_cast<uchar>(p[q] * f);
    }
  cv::circle(bgr, {width / 4, height / 2}, 5, cv::Scalar(80, 80, 255), cv::FILLED);
  cv::circle(bgr, {3 * width / 4, height / 2}, 5, cv::Scalar(80, 80, 255), cv::FILLED);
  cv::putText(bgr, "T:2023-Jun-03 16:30:33", {4, 14}, cv::FONT_HERSHEY_SIMPLEX, 0.45, cv::Scalar(255, 200, 255), 1);
  return bgr;
}

// DIR/images and DIR/labels_gt with frames [first, first + count), named with capture times
// `station_gap` minutes apart every `per_station` frames.
void WriteBurrowFrames(const std::string& dir, int first, int count, int per_station) {
  std::filesystem::create_directories(dir + "/images");
  std::filesystem::create_directories(dir + "/labels_gt");
  for (int i = first; i < first + count; ++i) {
    std::vector<cv::Rect2d> boxes;
    const cv::Mat frame = BurrowFrame(i, &boxes);
    char name[96];
    const int station = (i - first) / per_station;
    std::snprintf(name, sizeof name, "image_D2023-06-%02dT10-%02d-%02d-000000Z_%d", 3 + station, (i % 30), (i * 7) % 60, i);
    cv::imwrite(dir + "/images/" + name + ".jpg", frame, {cv::IMWRITE_JPEG_QUALITY, 92});
    std::ofstream out(dir + "/labels_gt/" + name + ".txt");
    for (const auto& b : boxes)
      out << "0 " << (b.x + b.width / 2) / frame.cols << " " << (b.y + b.height / 2) / frame.rows << " "
          << b.width / frame.cols << " " << b.height / frame.rows << "\n";
  }
}

}  // namespace rolamos::test

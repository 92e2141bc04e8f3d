#include "test_support.h"

#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <cmath>
#include <filesystem>

#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"
#include "synth/seafloor_texture.h"

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

}  // namespace rolamos::test

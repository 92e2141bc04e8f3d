// Helpers shared by the tests: scratch directories, generated images, the CLI, shared data.
#pragma once

#include <functional>
#include <string>

#include <opencv2/core.hpp>

#include "engine/features.h"
#include "rolamos/store.hpp"
#include "rolamos/survey.hpp"

namespace rolamos::test {

// A fresh directory under the build's temp area, removed when the object dies.
class ScratchDir {
 public:
  ScratchDir();
  ~ScratchDir();
  const std::string& path() const { return path_; }
  std::string operator/(const std::string& name) const { return path_ + "/" + name; }

 private:
  std::string path_;
};

// Two frames' SIFT-like features over the same ground: frame b is frame a (of `size`) moved by
// `a_to_b`. Each of a's 600 points that lands in b is found there too (its descriptor a little
// changed, its place off by up to a tenth of a pixel), and b has 600 features of its own.
void TwoFeatureViews(const cv::Matx33d& a_to_b, cv::Size size, Features* a, Features* b);

// A textured test image (procedural seafloor), BGR, optionally with a transparent border.
cv::Mat MakeImage(int width, int height, int channels = 3, int bits = 8, uint32_t seed = 1);

struct CommandResult {
  int exit_code = -1;
  std::string output;  // stdout and stderr together
};
// Runs the rolamos CLI with `args` (a shell-quoted string).
CommandResult RunCli(const std::string& args);
// Runs any shell command.
CommandResult RunShell(const std::string& command);
bool HaveCommand(const std::string& name);

// ../shared/data (or $ROLAMOS_SHARED_DATA) when it exists, "" otherwise.
std::string SharedData();

double Psnr(const cv::Mat& a, const cv::Mat& b);
// PSNR after one colour fit of a to b (per channel, gain and offset): geometry, not colour, as
// the map corrects lighting, exposure and the water's colour.
double PsnrAfterColourFit(const cv::Mat& a, const cv::Mat& b);

// The message of the rolamos::Error that `f` throws ("" if it throws none).
std::string ErrorOf(const std::function<void()>& f);
// PSNR of the colour channels where `b`'s alpha (last channel) is non-zero.
double MaskedPsnr(const cv::Mat& a, const cv::Mat& b);

// A small synthetic survey (480 x 360 frames, focal 420 px) over the procedural seafloor.
SurveyOptions SmallSurvey(int frames);
// The frames in `frames_dir` mosaicked into a new store at `store_dir` and composed (zstd tiles,
// lossless, so tests compare real pixels); patch_megapixels 0 keeps the engine's default.
Store MosaicAndCompose(const std::string& frames_dir, const std::string& store_dir, double patch_megapixels = 0);

// Where the store puts every stitched frame's 3 x 3 grid against where the survey's ground
// truth does, after one best-fit homography for the whole map: the distance of every point,
// global pixels. `aligned`: the frames' aligned frame_to_global; otherwise the online placement
// (patch_to_global_online, or patch_to_global, times frame_to_patch).
std::vector<double> ErrorsAgainstTruth(const Store& store, const Survey& truth, bool aligned = false);
double Rms(const std::vector<double>& errors);

// The survey's vehicle navigation as `compose --navigation` reads it (frame, position, altitude,
// heading), from its ground truth: texture pixel (X, Y) is map (500000 + 0.01 X, 5200000 - 0.01 Y)
// in EPSG:32755 (or, `latlon`, roughly the same place in degrees near 147 E, 43.5 S).
void WriteSurveyNavigation(const Survey& s, const std::string& path, double focal, bool latlon = false);

// Object identification data: 160 x 160 crops of generated seafloor with one object in the
// middle (a purple "disc", a pale "star" of spines, a dark "bar"), rotated, scaled and shifted
// at random; "background" crops hold none.
inline const std::vector<std::string> kShapeClasses = {"bar", "disc", "star"};
cv::Mat ShapeSample(const std::string& cls, uint32_t seed);
// DIR/<class>/NNN.png for each class (and background when asked), `per_class` each.
void WriteShapesDataset(const std::string& dir, int per_class, uint32_t seed, bool background = false);

// A survey frame of burrows (dark openings with a pale rim, 24..80 px) on seafloor texture,
// with vignetting, a light cone, two laser dots and a burned-in timestamp; `boxes` gets theirs.
cv::Mat BurrowFrame(int index, std::vector<cv::Rect2d>* boxes, int width = 640, int height = 480);
// DIR/images and DIR/labels_gt (YOLO) of frames [first, first + count), named with capture times
// that put every `per_station` frames in a station of their own.
void WriteBurrowFrames(const std::string& dir, int first, int count, int per_station = 100);

}  // namespace rolamos::test

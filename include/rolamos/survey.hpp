// Synthetic surveys: a simulated downward camera flown over a large image (or the procedural
// seafloor), rendered with underwater degradations, with the ground-truth homography of every
// frame. Tests, benchmarks and the README's main job use it: truth is known exactly.
#pragma once

#include <array>
#include <functional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "rolamos/progress.hpp"

namespace rolamos {

struct SurveyOptions {
  std::string texture;       // image to fly over, or several (a,b,c: bands top to bottom); "" = procedural seafloor
  int frame_width = 1292;    // the paper's camera
  int frame_height = 964;
  double focal_px = 1100.0;
  double fov_deg = 0;        // horizontal field of view; > 0 sets the focal length instead
  double gsd = 1.0;          // texture pixels per frame pixel at the nominal altitude
  std::string path = "lawnmower";  // lawnmower | spiral | random
  int frames = 60;
  double forward_overlap = 0.8;  // between consecutive frames
  double side_overlap = 0.3;     // between lawnmower lanes
  double altitude_jitter = 0.05;  // relative altitude change (smooth)
  // An ROV's approach to the seafloor: the first `descent_frames` frames (0: a third of them)
  // come down from `descent_from` times the altitude to it, at a steady speed, along the path;
  // from higher up the ground is smaller in the frame and the water takes more of its colour.
  double descent_from = 1;
  int descent_frames = 0;
  double tilt_deg = 2.0;          // roll/pitch amplitude (smooth)
  double attitude_jitter_deg = 0; // roll and pitch drawn independently for every frame (sd)
  bool lane_turns = true;         // lawnmower: false = the next lane starts turned 180 degrees
  int lanes = 0;                  // lawnmower: 0 = as many as the texture holds; N = N lanes of
                                  // frames / N frames (the procedural seafloor grows to hold them)
  double max_turn_deg = 15.0;     // random walk: the sharpest turn from one frame to the next
  bool overlay = false;           // a burned-in timestamp and two laser dots, fixed in the image
  // Look-alike ground: the texture's bottom-right quarter repeats its top-left quarter turned 180
  // degrees ("rotate") or mirrored left-right ("mirror"); "" = none. Frames over the two quarters
  // match each other by appearance, at the wrong place: what a map must not fold on.
  std::string repeat;
  // Degradations, each 0 to switch it off.
  double attenuation = 1.0;   // red/green loss with altitude
  double vignetting = 0.35;   // darkening at the corners
  double backscatter = 0.08;  // blue-green haze
  // Radial lens distortion, OpenCV's k1 (negative: barrel, as wide lenses; 0 = a pinhole). The
  // ground truth stays the pinhole's: frame_to_world maps undistorted pixels.
  double k1 = 0;
  double light_cone = 0;      // the vehicle's lights: a bright spot off the centre, 0..1 of brightness
  double exposure_jitter = 0; // per-frame exposure gain drawn around 1 (standard deviation)
  // Motion blur: the shutter open for this fraction of the time between frames (0 = a still
  // picture; 0.5 = 1/60 s at 30 frames/s), the frame smeared along the camera's own motion and
  // turn, centred on its pose (the ground truth). A dim seafloor needs long exposures.
  double motion_blur = 0;
  double noise = 2.0;         // sensor noise sigma, grey levels
  int particles = 40;         // marine snow per frame
  int jpeg_quality = 92;      // 0 = write PNG
  uint32_t seed = 1;
  // Also a video of the frames (.mp4: MPEG-4; .avi: Motion JPEG), relative to the survey
  // directory, at `video_fps` frames a second: what a camera feed looks like to `mosaic`.
  std::string video;
  double video_fps = 30;
  // Its codec: "" by the extension (.mp4 MPEG-4 part 2, .avi Motion JPEG), or "mpeg4", "h264"
  // (both .mp4; H.264 at libx264's default quality, as a vehicle streams), "mjpeg" (.avi).
  std::string video_codec;

  bool IsValid(std::string* error) const;
  double Focal() const;  // pixels: from fov_deg when given, else focal_px
  // The rectangle the camera centre needs (texture pixels) when the path fixes it (lawnmower
  // with `lanes`), else 0 x 0: the path adapts to the texture.
  cv::Size2d PathExtent() const;
};

struct SurveyFrame {
  int index = 0;
  std::string file;  // relative to the survey directory
  std::array<double, 9> frame_to_world{};  // frame pixel -> texture pixel
  std::array<double, 3> camera_position{};  // texture pixels; z is the altitude
  double yaw_deg = 0.0;
};

struct Survey {
  std::string texture;
  cv::Size texture_size;
  cv::Size frame_size;
  cv::Matx33d camera_matrix;
  std::vector<SurveyFrame> frames;
};

// Renders the survey into `dir` (frames/frame_NNNNN.{jpg,png} and ground_truth.json).
Survey WriteSurvey(const SurveyOptions& options, const std::string& dir,
                   const ProgressFn& progress = nullptr);
// Reads ground_truth.json of a survey directory.
Survey ReadSurvey(const std::string& dir);

}  // namespace rolamos

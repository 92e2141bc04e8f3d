#include <cstdio>

#include "command.h"
#include "rolamos/survey.hpp"
#include "util/progress.h"

namespace rolamos::cli {

struct SynthSwitches {
  SurveyOptions survey;
  std::string output;
  bool quiet = false;
};

static int RunSynth(const SynthSwitches& s) {
  Progress progress("synth", s.quiet);
  Survey survey = WriteSurvey(s.survey, s.output, [&](double f) { progress.Update(f); });
  progress.Done();
  std::printf("%s: %zu frames of %dx%d over %s (%dx%d), path %s, ground truth in "
              "ground_truth.json, %.1f s\n",
              s.output.c_str(), survey.frames.size(), survey.frame_size.width,
              survey.frame_size.height, survey.texture.c_str(), survey.texture_size.width,
              survey.texture_size.height, s.survey.path.c_str(), progress.ElapsedSeconds());
  return 0;
}

void AddSynthCommand(CLI::App& app, Runner* run) {
  auto s = std::make_shared<SynthSwitches>();
  auto& o = s->survey;
  auto* cmd = app.add_subcommand(
      "synth", "A synthetic survey over an image (or a procedural seafloor) with ground truth");
  cmd->add_option("texture", o.texture, "image to fly over, or several separated by commas (bands from top to bottom); default: a procedural seafloor");
  cmd->add_option("-o,--output", s->output, "survey directory to write")->required();
  cmd->add_option("--frames", o.frames, "number of frames")->capture_default_str();
  cmd->add_option("--path", o.path, "lawnmower, spiral, random, or inspect (an ROV pilot: transit, hold station, yaw in place, creep sideways)")->capture_default_str();
  cmd->add_option("--width", o.frame_width, "frame width")->capture_default_str();
  cmd->add_option("--height", o.frame_height, "frame height")->capture_default_str();
  cmd->add_option("--focal", o.focal_px, "focal length in pixels")->capture_default_str();
  cmd->add_option("--fov", o.fov_deg, "horizontal field of view, degrees (sets the focal length)");
  cmd->add_option("--gsd", o.gsd, "texture pixels per frame pixel")->capture_default_str();
  cmd->add_option("--overlap", o.forward_overlap, "forward overlap 0..0.98")->capture_default_str();
  cmd->add_option("--side-overlap", o.side_overlap, "lane overlap")->capture_default_str();
  cmd->add_option("--tilt", o.tilt_deg, "roll/pitch amplitude, degrees")->capture_default_str();
  cmd->add_option("--attitude-jitter", o.attitude_jitter_deg,
                  "roll and pitch drawn independently for every frame, standard deviation in degrees")
      ->capture_default_str();
  cmd->add_flag("!--no-turns", o.lane_turns, "lawnmower lanes join without turn frames (the next lane starts turned 180 degrees)");
  cmd->add_option("--lanes", o.lanes, "lawnmower: number of lanes (0 = as many as the texture holds)")
      ->capture_default_str();
  cmd->add_option("--max-turn", o.max_turn_deg, "random walk and inspect: sharpest turn per frame, degrees")
      ->capture_default_str();
  cmd->add_flag("--overlay", o.overlay, "burn a timestamp and two laser dots into every frame, as TV surveys do");
  cmd->add_option("--repeat", o.repeat,
                  "look-alike ground: the texture's bottom-right quarter repeats its top-left quarter turned 180 "
                  "degrees (rotate) or mirrored (mirror)");
  cmd->add_option("--altitude-jitter", o.altitude_jitter, "relative altitude change")
      ->capture_default_str();
  cmd->add_option("--attenuation", o.attenuation, "colour loss with depth (0 = off)")
      ->capture_default_str();
  cmd->add_option("--vignetting", o.vignetting, "corner darkening 0..1")->capture_default_str();
  cmd->add_option("--backscatter", o.backscatter, "haze (0 = off)")->capture_default_str();
  cmd->add_option("--k1", o.k1, "radial lens distortion (OpenCV's k1; negative = barrel, as wide lenses); the ground truth stays the pinhole's")
      ->capture_default_str();
  cmd->add_option("--light-cone", o.light_cone, "the vehicle's lights, a bright spot off the centre (0..1, 0 = off)")
      ->capture_default_str();
  cmd->add_option("--exposure-jitter", o.exposure_jitter, "per-frame exposure gain, standard deviation (0 = off)")
      ->capture_default_str();
  cmd->add_option("--motion-blur", o.motion_blur,
                  "shutter open for this share of the frame interval (0 = off; 0.5 = 1/60 s at 30 frames/s): "
                  "frames smeared along the camera's motion")
      ->capture_default_str();
  cmd->add_option("--descent-from", o.descent_from,
                  "an ROV's approach: the first frames come down from this many times the altitude to it (1 = none)")
      ->capture_default_str();
  cmd->add_option("--descent-frames", o.descent_frames, "frames the approach takes (0 = a third of them)")
      ->capture_default_str();
  cmd->add_option("--noise", o.noise, "sensor noise sigma")->capture_default_str();
  cmd->add_option("--particles", o.particles, "marine snow per frame")->capture_default_str();
  cmd->add_option("--jpeg", o.jpeg_quality, "JPEG quality (0 = PNG)")->capture_default_str();
  cmd->add_option("--seed", o.seed, "random seed")->capture_default_str();
  cmd->add_option("--video", o.video, "also write the frames as a video (.mp4 or .avi) in the survey directory");
  cmd->add_option("--video-fps", o.video_fps, "frame rate of --video")->capture_default_str();
  cmd->add_option("--video-codec", o.video_codec,
                  "codec of --video: mpeg4 or h264 (.mp4), mjpeg (.avi); default by the extension (.mp4 mpeg4)");
  cmd->add_flag("-q,--quiet", s->quiet, "no progress bar");
  cmd->callback([s, run] { *run = [s] { return RunSynth(*s); }; });
}

}  // namespace rolamos::cli

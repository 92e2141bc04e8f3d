#include "synth/camera_path.h"

#include <cmath>
#include <random>

namespace rolamos {
namespace {

// Smooth noise in [-1, 1] along the path: a sum of a few slow sines with random phases.
struct Wobble {
  double phase[3], freq[3];
  explicit Wobble(std::mt19937& rng) {
    std::uniform_real_distribution<double> p(0, 2 * CV_PI), f(0.03, 0.12);
    for (int i = 0; i < 3; ++i) {
      phase[i] = p(rng);
      freq[i] = f(rng) / (i + 1);
    }
  }
  double operator()(double t) const {
    double v = 0;
    for (int i = 0; i < 3; ++i) v += std::sin(freq[i] * t + phase[i]) / 3.0;
    return v;
  }
};

double WrapAngle(double a) {
  while (a > CV_PI) a -= 2 * CV_PI;
  while (a < -CV_PI) a += 2 * CV_PI;
  return a;
}

}  // namespace

cv::Matx33d WorldToFrame(const CameraPose& pose, const cv::Matx33d& K) {
  // World: x right, y down (texture axes), z into the seafloor; the camera sits at z = -altitude
  // looking along +z, so with no rotation its axes are the world's (no mirror).
  const double cr = std::cos(pose.roll), sr = std::sin(pose.roll);
  const double cp = std::cos(pose.pitch), sp = std::sin(pose.pitch);
  const double cy = std::cos(pose.yaw), sy = std::sin(pose.yaw);
  const cv::Matx33d Rx(1, 0, 0, 0, cr, -sr, 0, sr, cr);
  const cv::Matx33d Ry(cp, 0, sp, 0, 1, 0, -sp, 0, cp);
  // Yaw turns the camera about the vertical; world->camera is the inverse rotation.
  const cv::Matx33d Rz(cy, sy, 0, -sy, cy, 0, 0, 0, 1);
  const cv::Matx33d R = Rx * Ry * Rz;
  const cv::Vec3d C(pose.position[0], pose.position[1], -pose.position[2]);
  const cv::Vec3d t = -(R * C);
  const cv::Matx33d M(R(0, 0), R(0, 1), t[0], R(1, 0), R(1, 1), t[1], R(2, 0), R(2, 1), t[2]);
  return K * M;
}

namespace {

using PathPoints = std::vector<cv::Vec3d>;  // x, y, yaw per frame

// Lanes run along x (the frame's "forward" is its -y axis, so yaw = -90 deg for +x).
PathPoints LawnmowerPath(const SurveyOptions& o, const cv::Rect2d& area, double foot_w, double step) {
  PathPoints xy_yaw;
  const double lane_gap = foot_w * (1.0 - o.side_overlap);
  const int lanes = o.lanes > 0 ? o.lanes : std::max(1, static_cast<int>(std::floor(area.height / lane_gap)) + 1);
  // Room for the half-circle turns inside the area.
  const double r = lanes > 1 && o.lane_turns ? lane_gap / 2 : 0;
  const int per_lane = o.lanes > 0 ? (o.frames + o.lanes - 1) / o.lanes
                                   : std::max(2, static_cast<int>(std::max(step, area.width - 2 * r) / step));
  const double lane_start = area.x + r;
  const double lane_len = o.lanes > 0 ? (per_lane - 1) * step : std::max(step, area.width - 2 * r);
  // Lanes 0, 1, ..., L-1, then back L-2, ..., 0 and so on: every turn goes to the next lane,
  // and later passes fly over earlier ones again (revisits).
  auto lane_of = [&](int k) {
    if (lanes == 1) return 0;
    const int period = 2 * (lanes - 1);
    const int m = k % period;
    return m < lanes ? m : period - m;
  };
  int n = 0;
  for (int k = 0; n < o.frames; ++k) {
    const int lane = lane_of(k), next = lane_of(k + 1);
    const bool forward = k % 2 == 0;
    const double y = area.y + lane * lane_gap;
    const double yaw = forward ? -CV_PI / 2 : CV_PI / 2;
    for (int i = 0; i < per_lane && n < o.frames; ++i, ++n) {
      const double s = i * lane_len / (per_lane - 1);
      xy_yaw.emplace_back(forward ? lane_start + s : lane_start + lane_len - s, y, yaw);
    }
    if (lanes == 1 || !o.lane_turns) continue;  // without turns: the next lane starts turned
    // A half-circle to the next lane at half speed, heading along the arc, as a vehicle turns.
    const double dir = next > lane ? 1.0 : -1.0;
    const int turn_frames = std::max(2, static_cast<int>(std::ceil(CV_PI * r / (0.5 * step))));
    const double x_end = forward ? lane_start + lane_len : lane_start;
    for (int t = 1; t < turn_frames && n < o.frames; ++t, ++n) {
      const double theta = CV_PI * t / turn_frames;
      const double x = x_end + (forward ? 1 : -1) * r * std::sin(theta);
      const double phi = forward ? dir * theta : CV_PI - dir * theta;  // travel direction
      xy_yaw.emplace_back(x, y + dir * (r - r * std::cos(theta)), phi - CV_PI / 2);
    }
  }
  return xy_yaw;
}

PathPoints SpiralPath(const SurveyOptions& o, const cv::Rect2d& area, double foot_w, double step) {
  PathPoints xy_yaw;
  const cv::Point2d c(area.x + area.width / 2, area.y + area.height / 2);
  const double max_r = std::min(area.width, area.height) / 2;
  const double ring_gap = foot_w * (1.0 - o.side_overlap);
  double theta = 0, r = 0;
  for (int n = 0; n < o.frames; ++n) {
    xy_yaw.emplace_back(c.x + r * std::cos(theta), c.y + r * std::sin(theta),
                        theta + CV_PI);  // forward along the tangent
    const double arc = std::max(r, step);
    theta += step / arc;
    r = std::min(max_r, ring_gap * theta / (2 * CV_PI));
  }
  return xy_yaw;
}

// Where a vehicle heading `heading` from `p` should turn next: a random wander, or back towards
// the centre when three steps ahead leave the area (so the walk revisits). One distribution
// for the whole walk, drawn every frame: it hands out its normals in pairs.
struct Wander {
  std::normal_distribution<double> turn{0.0, 0.12};
};

double NextTurn(std::mt19937& rng, Wander& w, const cv::Rect2d& area, cv::Point2d p, double heading, double step) {
  const double wander = w.turn(rng);
  const cv::Point2d centre(area.x + area.width / 2, area.y + area.height / 2);
  const cv::Point2d ahead = p + 3 * step * cv::Point2d(std::cos(heading), std::sin(heading));
  if (area.contains(ahead)) return wander;
  return WrapAngle(std::atan2(centre.y - p.y, centre.x - p.x) - heading);
}

cv::Point2d Clamped(const cv::Rect2d& area, cv::Point2d p) {
  return {std::clamp(p.x, area.x, area.x + area.width), std::clamp(p.y, area.y, area.y + area.height)};
}

PathPoints RandomWalkPath(const SurveyOptions& o, const cv::Rect2d& area, double step, std::mt19937& rng) {
  PathPoints xy_yaw;
  Wander wander;
  const double max_turn = o.max_turn_deg * CV_PI / 180;  // a vehicle's turn rate per frame
  cv::Point2d p(area.x + area.width / 2, area.y + area.height / 2);
  double heading = 0;
  for (int n = 0; n < o.frames; ++n) {
    xy_yaw.emplace_back(p.x, p.y, heading - CV_PI / 2);
    heading = WrapAngle(heading + std::clamp(NextTurn(rng, wander, area, p, heading, step), -max_turn, max_turn));
    p = Clamped(area, p + step * cv::Point2d(std::cos(heading), std::sin(heading)));
  }
  return xy_yaw;
}

// An ROV pilot inspecting the seafloor: a transit, a stop that holds station (drifting a
// little), a yaw in place, then a sideways creep at a tenth of the speed; and again. The yaw
// turns at up to --max-turn a frame.
PathPoints InspectionPath(const SurveyOptions& o, const cv::Rect2d& area, double step, std::mt19937& rng) {
  PathPoints xy_yaw;
  Wander wander;
  const double max_turn = o.max_turn_deg * CV_PI / 180;
  std::uniform_real_distribution<double> yaw_by(CV_PI / 2, CV_PI), side(-1, 1);
  std::normal_distribution<double> drift(0.0, 0.02 * step);
  cv::Point2d p(area.x + area.width / 2, area.y + area.height / 2);
  double heading = 0;
  auto emit = [&](double motion_dir, double distance) {
    xy_yaw.emplace_back(p.x, p.y, heading - CV_PI / 2);
    p = Clamped(area, p + distance * cv::Point2d(std::cos(motion_dir), std::sin(motion_dir)));
  };
  while (static_cast<int>(xy_yaw.size()) < o.frames) {
    for (int i = 0; i < 40; ++i) {  // transit
      heading = WrapAngle(heading + std::clamp(NextTurn(rng, wander, area, p, heading, step), -max_turn, max_turn));
      emit(heading, step);
    }
    for (int i = 0; i < 20; ++i) {  // hold station
      emit(heading, 0);
      p = Clamped(area, p + cv::Point2d(drift(rng), drift(rng)));
    }
    const double turn = (side(rng) < 0 ? -1 : 1) * yaw_by(rng);  // yaw in place
    const int turn_frames = static_cast<int>(std::ceil(std::abs(turn) / max_turn));
    for (int i = 0; i < turn_frames; ++i) {
      heading = WrapAngle(heading + turn / turn_frames);
      emit(heading, 0);
    }
    const double crab = heading + (side(rng) < 0 ? -1 : 1) * CV_PI / 2;  // sideways creep
    for (int i = 0; i < 30; ++i) emit(crab, 0.1 * step);
  }
  xy_yaw.resize(o.frames);
  return xy_yaw;
}

}  // namespace

std::vector<CameraPose> PlanCameraPath(const SurveyOptions& o, const cv::Rect2d& area) {
  std::mt19937 rng(o.seed * 7919u + 13u);
  const double altitude = o.Focal() * o.gsd;
  // Footprint on the texture at nominal altitude; the camera moves along its own y axis.
  const double foot_w = o.frame_width * o.gsd, foot_h = o.frame_height * o.gsd;
  const double step = foot_h * (1.0 - o.forward_overlap);
  const PathPoints xy_yaw = o.path == "lawnmower" ? LawnmowerPath(o, area, foot_w, step)
                            : o.path == "spiral"  ? SpiralPath(o, area, foot_w, step)
                            : o.path == "inspect" ? InspectionPath(o, area, step, rng)
                                                  : RandomWalkPath(o, area, step, rng);

  Wobble alt(rng), roll(rng), pitch(rng);
  // The approach: from descent_from times the altitude down to it at a steady vertical speed.
  const int descent = o.descent_from > 1 ? (o.descent_frames > 0 ? o.descent_frames : o.frames / 3) : 0;
  auto approach = [&](double t) { return t >= descent ? 1.0 : o.descent_from - (o.descent_from - 1) * t / descent; };
  std::normal_distribution<double> jitter(0.0, o.attitude_jitter_deg * CV_PI / 180);
  std::vector<CameraPose> poses;
  for (size_t i = 0; i < xy_yaw.size(); ++i) {
    CameraPose pose;
    const double t = double(i);
    pose.position = cv::Vec3d(xy_yaw[i][0], xy_yaw[i][1], altitude * approach(t) * (1.0 + o.altitude_jitter * alt(t)));
    pose.yaw = WrapAngle(xy_yaw[i][2]);
    pose.roll = o.tilt_deg * CV_PI / 180 * roll(t) + (o.attitude_jitter_deg > 0 ? jitter(rng) : 0.0);
    pose.pitch = o.tilt_deg * CV_PI / 180 * pitch(t) + (o.attitude_jitter_deg > 0 ? jitter(rng) : 0.0);
    poses.push_back(pose);
  }
  return poses;
}

}  // namespace rolamos

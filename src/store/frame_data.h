// What the engine keeps of each patch's frames for the global map (docs/store-format.md, "frame
// links and features"), next to the patch's sidecar:
//  - links (patches/NNNNNN.links.json): matched pixels between two frames, found online; the
//    edges of the survey's graph that the engine already verified;
//  - features (patches/NNNNNN.features): each frame's strongest keypoints with SIFT descriptors
//    (128 bytes each, exactly as OpenCV computes them), so that loop closures and place
//    recognition need neither the frames on disk nor detection again.
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

// A frame of the store: its patch and its sequence number in the input the patch came from.
struct FrameId {
  int patch = 0;
  int index = 0;
  bool operator<(const FrameId& o) const { return patch != o.patch ? patch < o.patch : index < o.index; }
  bool operator==(const FrameId& o) const { return patch == o.patch && index == o.index; }
};

struct StoredLink {
  FrameId a, b;
  std::vector<cv::Point2f> in_a, in_b;  // pixels of the (rectified) frames
};

// How many keypoints a frame keeps: its strongest, spread over the frame, in rounds (each round
// the next strongest of each of 8 x 8 cells). The first kPrimaryStoredFeatures are what stores
// before session 42 kept, and what the global map matches first; the rest (the next rounds) only
// link pairs those leave unlinked. On degraded frames (noise, particles, backscatter) the strip
// two lanes share held too few of 400 to link them: the global map of small-degraded 1.63 ->
// 0.85 px (bench/RESULTS.md, session 42).
inline constexpr int kStoredFeatures = 800;
inline constexpr int kPrimaryStoredFeatures = 400;

struct StoredFeatures {
  int index = 0;                     // the frame's sequence number (its patch is the file's)
  std::vector<cv::Point2f> points;   // full-resolution pixels
  cv::Mat descriptors;               // CV_8U, points.size() x 128
};

// Atomic writes; reads throw Error naming the file and what is wrong.
void WriteFrameLinks(const std::string& path, const std::vector<StoredLink>& links);
std::vector<StoredLink> ReadFrameLinks(const std::string& path);
void WriteFrameFeatures(const std::string& path, const std::vector<StoredFeatures>& frames);
std::vector<StoredFeatures> ReadFrameFeatures(const std::string& path);

}  // namespace rolamos

#include "rolamos/global_align.hpp"

#include <chrono>
#include <cmath>
#include <filesystem>
#include <map>
#include <mutex>

#include <Eigen/Sparse>
#include <opencv2/calib3d.hpp>

#include "align/navigation_fit.h"
#include "align/stored_frames.h"
#include "rolamos/error.hpp"
#include "util/homography.h"
#include "util/parallel_for.h"

namespace rolamos {

bool AlignOptions::IsValid(std::string* error) const {
  if (!(search_radius > 0 && search_radius <= 3)) {
    *error = "search radius must be in (0, 3] frame widths";
    return false;
  }
  if (min_index_gap < 2 || max_pairs_per_frame < 1 || min_inliers < 8) {
    *error = "min index gap >= 2, pairs per frame >= 1 and min inliers >= 8 are needed";
    return false;
  }
  if (model != "similarity" && model != "affine") {
    *error = "alignment model \"" + model + "\" is not similarity or affine";
    return false;
  }
  if (!(min_loop_error_px >= 0)) {
    *error = "the loop error below which nothing is corrected cannot be negative";
    return false;
  }
  if (!(chain_weight > 0) || !(loop_weight > 0) || !(navigation_weight > 0)) {
    *error = "weights must be positive";
    return false;
  }
  return true;
}

namespace {

struct Frame {
  int patch = 0;
  size_t record = 0;   // index in the patch's frames
  int index = 0;       // sequence number in the survey
  std::string source;
  cv::Matx33d to_global;  // online placement
  cv::Size size;
};


// A correspondence between two frames' corrections: C_a(P) should equal C_b(Q), P and Q in
// online global pixels.
struct Link {
  int a, b;
  cv::Point2d P, Q;
  double weight;
  bool loop;
};

// Correction of frame i, around the survey's centre so the numbers stay well scaled:
// similarity x' = s x - r y + tx, y' = r x + s y + ty (4 unknowns from 4i), or affine
// x' = a x + b y + c, y' = d x + e y + f (6 unknowns from 6i). Both are linear in their unknowns,
// so the whole alignment is one sparse linear least-squares problem.
struct Solver {
  int n;
  bool affine;
  cv::Point2d centre;
  double unit;
  std::vector<Eigen::Triplet<double>> triplets;
  std::vector<double> rhs;
  int rows = 0;

  int k() const { return affine ? 6 : 4; }
  void Row(const std::vector<std::pair<int, double>>& terms, double value, double w) {
    for (const auto& [col, v] : terms) triplets.emplace_back(rows, col, w * v);
    rhs.push_back(w * value);
    ++rows;
  }
  // Coefficients of x' and y' of frame f at point p, times `sign`.
  void Terms(int f, cv::Point2d p, double sign, std::vector<std::pair<int, double>>* x,
             std::vector<std::pair<int, double>>* y) const {
    const int o = k() * f;
    if (affine) {
      *x = {{o, sign * p.x}, {o + 1, sign * p.y}, {o + 2, sign}};
      *y = {{o + 3, sign * p.x}, {o + 4, sign * p.y}, {o + 5, sign}};
    } else {
      *x = {{o, sign * p.x}, {o + 1, -sign * p.y}, {o + 2, sign}};
      *y = {{o, sign * p.y}, {o + 1, sign * p.x}, {o + 3, sign}};
    }
  }
  void Add(const Link& l) {
    std::vector<std::pair<int, double>> ax, ay, bx, by;
    Terms(l.a, (l.P - centre) / unit, 1, &ax, &ay);
    Terms(l.b, (l.Q - centre) / unit, -1, &bx, &by);
    ax.insert(ax.end(), bx.begin(), bx.end());
    ay.insert(ay.end(), by.begin(), by.end());
    Row(ax, 0, l.weight);
    Row(ay, 0, l.weight);
  }
  // Pulls frame i's point P (online global pixels) towards `target`.
  void Pull(int i, cv::Point2d P, cv::Point2d target, double w) {
    std::vector<std::pair<int, double>> x, y;
    Terms(i, (P - centre) / unit, 1, &x, &y);
    const cv::Point2d t = (target - centre) / unit;
    Row(x, t.x, w);
    Row(y, t.y, w);
  }
  // Holds frame i at identity (strong) or pulls it there (weak).
  void Hold(int i, double w) {
    const int o = k() * i;
    const std::vector<double> identity = affine ? std::vector<double>{1, 0, 0, 0, 1, 0} : std::vector<double>{1, 0, 0, 0};
    for (int j = 0; j < k(); ++j) Row({{o + j, 1}}, identity[static_cast<size_t>(j)], w);
  }
  std::vector<cv::Matx33d> Solve() {
    Eigen::SparseMatrix<double> A(rows, k() * n);
    A.setFromTriplets(triplets.begin(), triplets.end());
    Eigen::VectorXd b = Eigen::Map<Eigen::VectorXd>(rhs.data(), static_cast<long>(rhs.size()));
    const Eigen::SparseMatrix<double> AtA = A.transpose() * A;
    const Eigen::VectorXd Atb = A.transpose() * b;
    Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt(AtA);
    if (ldlt.info() != Eigen::Success) Fail("align", "the alignment system is singular");
    const Eigen::VectorXd x = ldlt.solve(Atb);
    std::vector<cv::Matx33d> out;
    const cv::Matx33d to_unit(1 / unit, 0, -centre.x / unit, 0, 1 / unit, -centre.y / unit, 0, 0, 1);
    const cv::Matx33d from_unit = to_unit.inv();
    for (int i = 0; i < n; ++i) {
      const double* v = x.data() + k() * i;
      const cv::Matx33d c = affine ? cv::Matx33d(v[0], v[1], v[2], v[3], v[4], v[5], 0, 0, 1)
                                   : cv::Matx33d(v[0], -v[1], v[2], v[1], v[0], v[3], 0, 0, 1);
      out.push_back(from_unit * c * to_unit);
    }
    return out;
  }
};

// A frame point with its place on the map from the navigation.
struct NavPoint {
  int frame;
  cv::Point2d P;    // online global pixels
  cv::Point2d map;  // map units
};

// Median distance on the map between frame centres (every 5th point) placed by `C` and their
// navigation, after the best similarity; also returns that similarity.
double NavigationResidual(const std::vector<NavPoint>& nav, const std::vector<cv::Matx33d>* C, cv::Matx33d* to_map) {
  std::vector<cv::Point2d> from, to;
  for (const auto& p : nav) {
    from.push_back(C ? ApplyHomography((*C)[static_cast<size_t>(p.frame)], p.P) : p.P);
    to.push_back(p.map);
  }
  const std::optional<cv::Matx33d> fit = FitSimilarity(from, to);
  if (!fit) Fail("align", "the navigation does not fit any similarity transform of the placement");
  *to_map = *fit;
  std::vector<double> d;
  for (size_t i = 0; i < from.size(); i += 5) d.push_back(cv::norm(ApplyHomography(*to_map, from[i]) - to[i]));
  std::nth_element(d.begin(), d.begin() + static_cast<long>(d.size() / 2), d.end());
  return d[d.size() / 2];
}

std::vector<cv::Point2d> Grid(cv::Size s) {
  std::vector<cv::Point2d> g;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) g.emplace_back(i * (s.width - 1) / 2.0, j * (s.height - 1) / 2.0);
  return g;
}

}  // namespace

AlignSummary AlignStore(Store store, const AlignOptions& options, const ProgressFn& progress) {
  std::string error;
  if (!options.IsValid(&error)) Fail("align options", error);
  const auto start = std::chrono::steady_clock::now();
  // 1. Every stitched frame at its online place.
  std::vector<Frame> frames;
  std::map<int, PatchSidecar> sidecars;
  for (const auto& entry : store.patches()) {
    PatchSidecar s = store.ReadSidecar(entry.id);
    if (!s.patch_to_global) Fail(store.dir(), "patch " + std::to_string(s.id) + " is not placed: run `rolamos compose` first");
    // Always from the online placement, so aligning again gives the same result.
    const Homography online = s.patch_to_global_online.value_or(*s.patch_to_global);
    if (!s.frame_size) Fail(store.PatchSidecarPath(s.id), "has no frame_size (not written by rolamos mosaic)");
    for (size_t k = 0; k < s.frames.size(); ++k) {
      Frame f;
      f.patch = s.id;
      f.record = k;
      f.index = s.frames[k].index;
      f.source = s.frames[k].source;
      f.to_global = ToMatx(online) * ToMatx(s.frames[k].frame_to_patch);
      f.size = cv::Size((*s.frame_size)[0], (*s.frame_size)[1]);
      frames.push_back(f);
    }
    sidecars[s.id] = std::move(s);
  }
  if (frames.size() < 2) Fail(store.dir(), "has fewer than two stitched frames");
  std::sort(frames.begin(), frames.end(), [](const Frame& a, const Frame& b) { return a.index < b.index; });
  const int n = static_cast<int>(frames.size());
  AlignSummary summary;
  summary.frames = n;

  // Navigation points: five near each frame's centre.
  std::vector<NavPoint> nav;
  for (int i = 0; i < n && !options.navigation.empty(); ++i) {
    const Frame& f = frames[static_cast<size_t>(i)];
    const FrameNavigation* fn = FindFrameNavigation(options.navigation, f.source);
    if (!fn) continue;
    std::vector<cv::Point2d> global, map;
    AddNavigationPoints(*fn, f.to_global, f.size, &global, &map);
    for (size_t k = 0; k < global.size(); ++k) nav.push_back({i, global[k], map[k]});
    ++summary.navigation_frames;
  }
  if (!options.navigation.empty() && summary.navigation_frames < 2)
    Fail(store.dir(), "fewer than two stitched frames have navigation (are the frame names those of the CSV?)");
  cv::Matx33d to_map = cv::Matx33d::eye();
  if (!nav.empty()) {
    summary.navigation_before_m = NavigationResidual(nav, nullptr, &to_map);
    // The online frame is the first frame's view, in perspective when that frame was tilted: a
    // homography, not a similarity, from the map. The placements are first carried into a frame
    // similar to the map (the homography, then the similarity back to pixels), so that the chain
    // and the navigation disagree only where the survey really drifted.
    if (summary.navigation_frames >= 4) {
      std::vector<cv::Point2d> from, to;
      cv::Point2d mean(0, 0);
      for (const auto& p : nav) mean += p.map;
      mean *= 1.0 / nav.size();
      for (const auto& p : nav) from.push_back(p.P), to.push_back(p.map - mean);
      const cv::Mat H = cv::findHomography(from, to, cv::LMEDS);
      if (!H.empty()) {
        const cv::Matx33d rectify = to_map.inv() * cv::Matx33d(1, 0, mean.x, 0, 1, mean.y, 0, 0, 1) * cv::Matx33d(H);
        for (auto& f : frames) f.to_global = rectify * f.to_global;
        for (auto& p : nav) p.P = ApplyHomography(rectify, p.P);
      }
    }
  }

  std::vector<Link> links;
  // 2. The chain: consecutive frames keep their online relative placement (a 3 x 3 grid).
  for (int i = 0; i + 1 < n; ++i) {
    const Frame& a = frames[static_cast<size_t>(i)];
    for (const cv::Point2d p : Grid(a.size)) {
      const cv::Point2d P = ApplyHomography(a.to_global, p);
      links.push_back({i, i + 1, P, P, options.chain_weight, false});
    }
    ++summary.chain_links;
  }
  // 3. Loop pairs: frames near each other on the map but apart in time, matched for real.
  std::vector<cv::Point2d> centre(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i)
    centre[static_cast<size_t>(i)] = ApplyHomography(frames[static_cast<size_t>(i)].to_global,
                                           {frames[static_cast<size_t>(i)].size.width / 2.0, frames[static_cast<size_t>(i)].size.height / 2.0});
  std::vector<std::pair<int, int>> candidates;
  for (int i = 0; i < n; ++i) {
    std::vector<std::pair<double, int>> near;
    const double radius = options.search_radius * frames[static_cast<size_t>(i)].size.width;
    for (int j = i + 1; j < n; ++j) {
      if (frames[static_cast<size_t>(j)].index - frames[static_cast<size_t>(i)].index < options.min_index_gap) continue;
      const double d = cv::norm(centre[static_cast<size_t>(i)] - centre[static_cast<size_t>(j)]);
      if (d < radius) near.emplace_back(d, j);
    }
    std::sort(near.begin(), near.end());
    for (size_t k = 0; k < near.size() && k < static_cast<size_t>(options.max_pairs_per_frame); ++k)
      candidates.emplace_back(i, near[k].second);
  }
  const FeatureOptions fo = StoredFrameFeatureOptions();
  const FeatureExtractor extractor(fo);
  // Each frame is described once, whichever pair asks first.
  std::map<int, std::shared_ptr<const Features>> cache;
  std::mutex mutex;
  auto features = [&](int i) -> std::shared_ptr<const Features> {
    {
      std::lock_guard<std::mutex> lock(mutex);
      auto it = cache.find(i);
      if (it != cache.end()) return it->second;
    }
    auto f = std::make_shared<const Features>(DescribeStoredFrame(
        StoredFramePath(frames[static_cast<size_t>(i)].source, options.frames_dir), extractor));
    std::lock_guard<std::mutex> lock(mutex);
    return cache.emplace(i, f).first->second;
  };
  std::vector<std::vector<Link>> found(candidates.size());
  std::atomic<int> done{0};
  ParallelFor(static_cast<long long>(candidates.size()), [&](long long c, int) {
    const auto [i, j] = candidates[static_cast<size_t>(c)];
    const VerifiedMatch v = MatchVerified(*features(i), *features(j), fo, options.min_inliers);
    // Up to 60 inliers, evenly through the list, as point pairs in online global pixels.
    const int step = std::max(1, v.inliers / 60);
    int seen = 0;
    for (size_t k = 0; v.inliers > 0 && k < v.inlier.size(); ++k) {
      if (!v.inlier[k] || (seen++ % step)) continue;
      found[static_cast<size_t>(c)].push_back({i, j, ApplyHomography(frames[static_cast<size_t>(i)].to_global, v.matches.from[k]),
                                               ApplyHomography(frames[static_cast<size_t>(j)].to_global, v.matches.to[k]),
                                               options.loop_weight, true});
    }
    if (progress) progress(0.9 * ++done / std::max<size_t>(1, candidates.size()));
  });
  summary.pairs_tried = static_cast<int>(candidates.size());
  double before = 0;
  int loop_points = 0;
  for (const auto& f : found) {
    summary.pairs_found += !f.empty();
    for (const auto& l : f) {
      links.push_back(l);
      before += std::pow(cv::norm(l.P - l.Q), 2);
      ++loop_points;
    }
  }
  summary.loop_error_before_px = loop_points ? std::sqrt(before / loop_points) : 0;
  // Loops that already close within the matching noise reveal no drift: correcting them would
  // only spread that noise over the map (measured: 0.63 -> 0.90 px on a survey whose loops closed
  // to 0.7 px). The online placement stays.
  if (nav.empty() && (loop_points == 0 || summary.loop_error_before_px < options.min_loop_error_px)) {
    summary.loop_error_after_px = summary.loop_error_before_px;
    summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (progress) progress(1.0);
    return summary;
  }
  summary.corrected = true;
  // With navigation, loops that already close are left out of the solution for the same reason.
  if (summary.loop_error_before_px < options.min_loop_error_px)
    links.erase(std::remove_if(links.begin(), links.end(), [](const Link& l) { return l.loop; }), links.end());

  // 4. Solve for the corrections: every frame weakly pulled to its place; the first frame held,
  // or with navigation, every frame pulled towards it (the similarity to the map refitted a few
  // times as the placement moves).
  double w = 0;
  for (const auto& f : frames) w = std::max(w, double(f.size.width));
  std::vector<cv::Matx33d> C;
  for (int round = 0; round < (nav.empty() ? 1 : 4); ++round) {
    Solver solver;
    solver.n = n;
    solver.affine = options.model == "affine";
    solver.unit = w;
    solver.centre = centre[0];
    for (const auto& l : links) solver.Add(l);
    const cv::Matx33d from_map = to_map.inv();
    for (const auto& p : nav) solver.Pull(p.frame, p.P, ApplyHomography(from_map, p.map), options.navigation_weight);
    solver.Hold(0, nav.empty() ? 1e3 : 1e-4);
    for (int i = 1; i < n; ++i) solver.Hold(i, 1e-4);
    C = solver.Solve();
    if (!nav.empty()) summary.navigation_after_m = NavigationResidual(nav, &C, &to_map);
  }
  double after = 0;
  for (const auto& l : links)
    if (l.loop) after += std::pow(cv::norm(ApplyHomography(C[static_cast<size_t>(l.a)], l.P) - ApplyHomography(C[static_cast<size_t>(l.b)], l.Q)), 2);
  summary.loop_error_after_px = loop_points ? std::sqrt(after / loop_points) : 0;

  // 5. New places: frames record theirs; each patch gets the homography that best carries its
  // frames (through their frame_to_patch) to them.
  std::map<int, std::vector<cv::Point2d>> patch_pts, global_pts;
  for (int i = 0; i < n; ++i) {
    const Frame& f = frames[static_cast<size_t>(i)];
    const cv::Matx33d aligned = C[static_cast<size_t>(i)] * f.to_global;
    PatchSidecar& s = sidecars[f.patch];
    s.frames[f.record].frame_to_global = ToArray9(aligned);
    const cv::Matx33d to_patch = ToMatx(s.frames[f.record].frame_to_patch);
    for (const cv::Point2d p : Grid(f.size)) {
      patch_pts[f.patch].push_back(ApplyHomography(to_patch, p));
      global_pts[f.patch].push_back(ApplyHomography(aligned, p));
    }
  }
  for (auto& [id, s] : sidecars) {
    if (!s.patch_to_global_online) s.patch_to_global_online = *s.patch_to_global;
    const cv::Mat H = cv::findHomography(patch_pts[id], global_pts[id], 0);
    if (H.empty()) Fail(store.PatchSidecarPath(id), "its frames give no patch placement");
    s.patch_to_global = ToArray9(cv::Matx33d(H));
    s.aligned = true;
    store.UpdateSidecar(s);
  }
  if (progress) progress(1.0);
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

}  // namespace rolamos

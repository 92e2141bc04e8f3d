#include "geometry/plane_adjustment.h"

#include <chrono>
#include <algorithm>
#include <cmath>

#include <ceres/ceres.h>

#include "geometry/link_transfer.h"

namespace rolamos {

bool PlaneAdjustmentOptions::IsValid(std::string* error) const {
  if (loss != "huber" && loss != "cauchy") {
    *error = "loss \"" + loss + "\" is not huber or cauchy";
    return false;
  }
  if (!(loss_px > 0) || max_iterations < 1 || !(max_tilt_deg > 0 && max_tilt_deg < 80) || threads < 1) {
    *error = "plane adjustment settings are out of range (loss scale > 0, iterations >= 1, tilt limit in (0, 80))";
    return false;
  }
  return true;
}

namespace {

// How many matched pairs a link stands for: the sum of its pairs' squared weights.
double PairCount(const PlaneLink& l) {
  if (l.pair_weight.empty()) return double(l.in_a.size());
  double n = 0;
  for (size_t i = 0; i < l.in_a.size(); ++i) n += PairWeight(l, i) * PairWeight(l, i);
  return n;
}

// The ground under a frame's pixel against where navigation puts it.
struct GroundResidual {
  GroundResidual(const GroundPrior& p, double cx, double cy) : p(p), cx(cx), cy(cy) {}
  template <typename T>
  bool operator()(const T* e, const T* c, const T* f, T* r) const {
    T R[9];
    PlaneRotation(e, R);
    const T v[3] = {(T(p.pixel.x) - T(cx)) / f[0], (T(p.pixel.y) - T(cy)) / f[0], T(1)};
    T d[3];
    for (int k = 0; k < 3; ++k) d[k] = R[k] * v[0] + R[3 + k] * v[1] + R[6 + k] * v[2];
    if (!(d[2] > T(1e-6))) return false;
    const T s = -c[2] / d[2];
    r[0] = (c[0] + s * d[0] - T(p.xy.x)) / T(p.sigma_px);
    r[1] = (c[1] + s * d[1] - T(p.xy.y)) / T(p.sigma_px);
    return true;
  }
  GroundPrior p;
  double cx, cy;
};

}  // namespace

namespace {

// With `scatter`, the pairs' scatter about a compressed link's points counts as those pairs
// would (what is reported); without, only how far the poses leave the points (what the solve
// judges a link by: 10,000-frame surveys came out 0.50 px against 2.47 with the scatter in the
// robust loss and the drops, bench/RESULTS.md 2026-11-26 (5)).
double TransferRms(const std::vector<PlanePose>& poses, double focal, cv::Size frame, const std::vector<PlaneLink>& links,
                   bool scatter) {
  const cv::Matx33d K = CameraMatrix(focal, frame);
  double sum = 0, n = 0;
  for (const auto& l : links) {
    const cv::Matx33d H = PlaneToFrame(poses[size_t(l.b)], K) * FrameToPlane(poses[size_t(l.a)], K);
    for (size_t i = 0; i < l.in_a.size(); ++i) {
      const cv::Vec3d q = H * cv::Vec3d(l.in_a[i].x, l.in_a[i].y, 1);
      const double w2 = PairWeight(l, i) * PairWeight(l, i);
      sum += w2 * (std::pow(q[0] / q[2] - l.in_b[i].x, 2) + std::pow(q[1] / q[2] - l.in_b[i].y, 2));
      n += w2;
    }
    if (scatter && !l.in_a.empty()) sum += PairCount(l) * l.scatter_px * l.scatter_px;
  }
  return n > 0 ? std::sqrt(sum / n) : 0.0;
}

}  // namespace

double PlaneTransferRms(const std::vector<PlanePose>& poses, double focal, cv::Size frame,
                        const std::vector<PlaneLink>& links) {
  return TransferRms(poses, focal, frame, links, /*scatter=*/true);
}

namespace {

// One solve over the links not dropped.
PlaneAdjustment SolveOnce(std::vector<PlanePose>* poses, double* focal, cv::Size frame,
                          const std::vector<PlaneLink>& links, const std::vector<char>& dropped, int anchor,
                          const std::vector<char>& held, const std::vector<GroundPrior>& priors,
                          const PlaneAdjustmentOptions& o) {
  PlaneAdjustment result;
  const size_t n = poses->size();
  std::vector<std::array<double, 3>> angles(n), centres(n);
  for (size_t i = 0; i < n; ++i) {
    const PlanePose& p = (*poses)[i];
    angles[i] = {p.yaw, p.pitch, p.roll};
    centres[i] = {p.centre[0], p.centre[1], p.centre[2]};
  }
  const double cx = (frame.width - 1) / 2.0, cy = (frame.height - 1) / 2.0;
  ceres::Problem::Options po;
  po.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(po);
  std::vector<std::unique_ptr<ceres::LossFunction>> owned_losses;  // per-link losses outlive the problem
  std::vector<char> used(n, 0);
  for (size_t k = 0; k < links.size(); ++k) {
    const PlaneLink& l = links[k];
    if (dropped[k] || l.a < 0 || l.b < 0 || size_t(l.a) >= n || size_t(l.b) >= n || l.a == l.b) continue;
    if (o.per_link && !l.in_a.empty()) {
      auto* cost = new LinkTransferCost(&l, cx, cy);
      // The knee where the link's RMS (over the pairs it stands for) reaches loss_px.
      const double a = o.loss_px * std::sqrt(PairCount(l)) * l.weight;
      // A trusted link is not discounted: its pull grows with how far off it is.
      ceres::LossFunction* link_loss =
          l.trusted ? nullptr
          : o.loss == "cauchy" ? static_cast<ceres::LossFunction*>(new ceres::CauchyLoss(a))
                               : new ceres::HuberLoss(a);
      problem.AddResidualBlock(cost, link_loss, angles[size_t(l.a)].data(), centres[size_t(l.a)].data(),
                               angles[size_t(l.b)].data(), centres[size_t(l.b)].data(), focal);
      if (link_loss) owned_losses.emplace_back(link_loss);
      result.residuals += static_cast<int>(l.in_a.size());
      used[size_t(l.a)] = used[size_t(l.b)] = 1;
      continue;
    }
    if (!l.in_a.empty()) {
      // A trusted link is not discounted (knee 0).
      auto* cost = new LinkTransferCost(&l, cx, cy, l.trusted ? 0.0 : o.loss_px, o.loss == "cauchy");
      problem.AddResidualBlock(cost, nullptr, angles[size_t(l.a)].data(), centres[size_t(l.a)].data(),
                               angles[size_t(l.b)].data(), centres[size_t(l.b)].data(), focal);
      result.residuals += static_cast<int>(l.in_a.size());
    }
    used[size_t(l.a)] = used[size_t(l.b)] = 1;
  }
  for (const auto& p : priors) {
    if (p.frame < 0 || size_t(p.frame) >= n || !used[size_t(p.frame)]) continue;
    // Robust too: navigation that contradicts vision for part of a survey (a bad fix, a jump)
    // is discounted beyond three of its sigmas instead of bending the map towards it.
    auto* prior_loss = new ceres::CauchyLoss(3.0);
    owned_losses.emplace_back(prior_loss);
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<GroundResidual, 2, 3, 3, 1>(new GroundResidual(p, cx, cy)),
                             prior_loss, angles[size_t(p.frame)].data(), centres[size_t(p.frame)].data(), focal);
  }
  if (result.residuals == 0) {
    result.message = "no links to adjust";
    return result;
  }
  const double tilt = o.max_tilt_deg * CV_PI / 180;
  for (size_t i = 0; i < n; ++i) {
    if (!used[i]) continue;
    const bool hold = i < held.size() && held[i];
    if (hold) {
      problem.SetParameterBlockConstant(angles[i].data());
      problem.SetParameterBlockConstant(centres[i].data());
      continue;
    }
    if (int(i) == anchor && priors.empty()) {
      problem.SetManifold(angles[i].data(), new ceres::SubsetManifold(3, {0}));
      problem.SetParameterBlockConstant(centres[i].data());
    }
    for (int k = 1; k < 3; ++k) {
      problem.SetParameterLowerBound(angles[i].data(), k, -tilt);
      problem.SetParameterUpperBound(angles[i].data(), k, tilt);
    }
    problem.SetParameterUpperBound(centres[i].data(), 2, -1e-3);  // above the plane
  }
  if (!o.refine_focal) {
    problem.SetParameterBlockConstant(focal);
  } else {
    // Where the cameras' attitudes hardly change, the focal length is barely observable: it
    // must not wander off to a degenerate camera.
    const double start = *focal;
    problem.SetParameterLowerBound(focal, 0, start / 3);
    problem.SetParameterUpperBound(focal, 0, start * 3);
  }
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  so.max_num_iterations = o.max_iterations;
  so.num_threads = o.threads;
  so.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  result.iterations = static_cast<int>(summary.iterations.size());
  result.ok = summary.IsSolutionUsable();
  if (!result.ok) {
    result.message = summary.message;
    return result;
  }
  for (size_t i = 0; i < n; ++i) {
    PlanePose& p = (*poses)[i];
    p.yaw = angles[i][0];
    p.pitch = angles[i][1];
    p.roll = angles[i][2];
    p.centre = cv::Vec3d(centres[i][0], centres[i][1], centres[i][2]);
  }
  return result;
}

// Links whose loss would split the frames they tie together (bridges of the graph, Tarjan's
// algorithm, iterative: surveys are long chains). Such a link is never dropped: without it, part
// of the map would float free, however well each part fits.
std::vector<char> Bridges(size_t n, const std::vector<PlaneLink>& links, const std::vector<char>& dropped) {
  std::vector<std::vector<std::pair<int, size_t>>> adj(n);  // (neighbour, link)
  for (size_t k = 0; k < links.size(); ++k) {
    if (dropped[k] || links[k].a == links[k].b) continue;
    adj[size_t(links[k].a)].emplace_back(links[k].b, k);
    adj[size_t(links[k].b)].emplace_back(links[k].a, k);
  }
  std::vector<char> bridge(links.size(), 0);
  std::vector<int> order(n, -1), low(n, 0);
  int counter = 0;
  struct Frame {
    int node;
    size_t via;   // the link it was reached by (SIZE_MAX at a root)
    size_t next;  // next neighbour to look at
  };
  for (size_t root = 0; root < n; ++root) {
    if (order[root] >= 0) continue;
    std::vector<Frame> stack{{int(root), SIZE_MAX, 0}};
    order[root] = low[root] = counter++;
    while (!stack.empty()) {
      Frame& f = stack.back();
      if (f.next < adj[size_t(f.node)].size()) {
        const auto [v, k] = adj[size_t(f.node)][f.next++];
        if (k == f.via) continue;
        if (order[size_t(v)] < 0) {
          order[size_t(v)] = low[size_t(v)] = counter++;
          stack.push_back({v, k, 0});
        } else {
          low[size_t(f.node)] = std::min(low[size_t(f.node)], order[size_t(v)]);
        }
        continue;
      }
      const Frame done = f;
      stack.pop_back();
      if (!stack.empty()) {
        const int parent = stack.back().node;
        low[size_t(parent)] = std::min(low[size_t(parent)], low[size_t(done.node)]);
        if (low[size_t(done.node)] > order[size_t(parent)]) bridge[done.via] = 1;
      }
    }
  }
  return bridge;
}

double LinkRms(const std::vector<PlanePose>& poses, double focal, cv::Size frame, const PlaneLink& l) {
  return TransferRms(poses, focal, frame, {l}, /*scatter=*/false);
}

}  // namespace

PlaneAdjustment AdjustPlanePoses(std::vector<PlanePose>* poses, double* focal, cv::Size frame,
                                 const std::vector<PlaneLink>& links, int anchor,
                                 const std::vector<char>& held, const std::vector<GroundPrior>& priors,
                                 const PlaneAdjustmentOptions& o) {
  const auto start = std::chrono::steady_clock::now();
  PlaneAdjustment result;
  std::string error;
  if (!o.IsValid(&error)) {
    result.message = error;
    return result;
  }
  result.initial_rms_px = PlaneTransferRms(*poses, *focal, frame, links);
  result.dropped.assign(links.size(), 0);
  const size_t n = poses->size();
  for (int round = 0;; ++round) {
    PlaneAdjustment r = SolveOnce(poses, focal, frame, links, result.dropped, anchor, held, priors, o);
    result.ok = r.ok;
    result.message = r.message;
    result.residuals = r.residuals;
    result.iterations += r.iterations;
    if (!r.ok || o.drop_link_px <= 0 || round + 1 >= o.rounds) break;
    // The worst links beyond the bound go, if every frame keeps another link.
    std::vector<int> degree(n, 0);
    std::vector<std::pair<double, size_t>> bad;
    for (size_t k = 0; k < links.size(); ++k) {
      if (result.dropped[k]) continue;
      ++degree[size_t(links[k].a)];
      ++degree[size_t(links[k].b)];
      const double rms = LinkRms(*poses, *focal, frame, links[k]);
      if (rms > o.drop_link_px && !links[k].trusted) bad.emplace_back(rms, k);
    }
    if (bad.empty()) break;
    // Only the links far worse than the typical one, and a few at a time: when much is wrong,
    // the solution is, not the links.
    std::vector<double> all_rms;
    for (size_t k = 0; k < links.size(); ++k)
      if (!result.dropped[k]) all_rms.push_back(LinkRms(*poses, *focal, frame, links[k]));
    std::nth_element(all_rms.begin(), all_rms.begin() + all_rms.size() / 2, all_rms.end());
    const double typical = all_rms[all_rms.size() / 2];
    bad.erase(std::remove_if(bad.begin(), bad.end(), [&](const auto& b) { return b.first < 4 * typical; }), bad.end());
    std::sort(bad.rbegin(), bad.rend());
    bad.resize(std::min({bad.size(), std::max<size_t>(1, all_rms.size() / 10), size_t(200)}));
    int dropped_now = 0;
    for (const auto& [rms, k] : bad) {
      const PlaneLink& l = links[k];
      if (degree[size_t(l.a)] <= 1 || degree[size_t(l.b)] <= 1) continue;
      if (Bridges(n, links, result.dropped)[k]) continue;
      --degree[size_t(l.a)];
      --degree[size_t(l.b)];
      result.dropped[k] = 1;
      ++result.links_dropped;
      ++dropped_now;
    }
    if (dropped_now == 0) break;
  }
  std::vector<PlaneLink> kept;
  for (size_t k = 0; k < links.size(); ++k)
    if (!result.dropped[k]) kept.push_back(links[k]);
  result.final_rms_px = PlaneTransferRms(*poses, *focal, frame, kept);
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

}  // namespace rolamos

#include "rolamos/global_align.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <map>
#include <numeric>
#include <set>
#include <unordered_map>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "align/navigation_fit.h"
#include "align/retrieval.h"
#include "align/stored_frames.h"
#include "engine/patch_adjustment.h"
#include "engine/registration.h"
#include "geometry/plane_adjustment.h"
#include "rolamos/error.hpp"
#include "store/frame_data.h"
#include "util/homography.h"
#include "util/parallel_for.h"

namespace rolamos {

bool AlignOptions::IsValid(std::string* error) const {
  if (retrieval_candidates < 0 || vocabulary < 2 || loops_per_frame < 0 || min_index_gap < 1 ||
      min_inliers < 8 || pairs_per_edge < 4 || !(loop_overlap > 0 && loop_overlap < 1) || !(loss_px > 0) ||
      !(navigation_sigma_m > 0) || threads < 0) {
    *error = "align settings are out of range (at least 8 inliers and 4 pairs an edge, overlap in (0, 1), "
             "positive loss and navigation sigma)";
    return false;
  }
  return true;
}

namespace {

struct Node {
  int patch = 0;         // patch id
  size_t record = 0;     // index in the patch's frames
  int index = 0;         // sequence number
  std::string source;
  cv::Matx33d to_patch;  // the online placement
  std::vector<cv::Point2f> points;
  cv::Mat descriptors;   // CV_8U, n x 128
};

enum EdgeKind { kOnline = 0, kRetrieval = 1, kLoop = 2 };

struct Edge {
  int a = 0, b = 0;
  std::vector<cv::Point2f> in_a, in_b;
  EdgeKind kind = kOnline;
};

// Union-find over frames.
struct Components {
  std::vector<int> parent;
  explicit Components(size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0); }
  int Find(int i) {
    while (parent[size_t(i)] != i) i = parent[size_t(i)] = parent[size_t(parent[size_t(i)])];
    return i;
  }
  bool Join(int a, int b) {
    a = Find(a), b = Find(b);
    if (a == b) return false;
    parent[size_t(std::max(a, b))] = std::min(a, b);
    return true;
  }
};

// At most `n` pairs spread over frame a (Thin's grid), as the optimisation wants them.
Edge ThinEdge(Edge e, int n, cv::Size frame) {
  FrameLink l{e.a, e.b, e.in_a, e.in_b};
  l = Thin(std::move(l), n, frame);
  e.in_a = std::move(l.in_a);
  e.in_b = std::move(l.in_b);
  return e;
}

Features AsFeatures(const Node& n) {
  Features f;
  f.points = n.points;
  n.descriptors.convertTo(f.descriptors, CV_32F);
  f.norm = cv::NORM_L2;
  return f;
}

// Two frames that see the same ground, for real: matches one RANSAC homography explains, a motion
// a camera over the seafloor can make, enough inliers. `guess` (a -> b), when given, guides the
// matching.
bool VerifyPair(const Node& a, const Node& b, const cv::Matx33d* guess, cv::Size frame, const AlignOptions& o,
                Edge* out) {
  if (a.points.size() < size_t(o.min_inliers) || b.points.size() < size_t(o.min_inliers)) return false;
  const Features fa = AsFeatures(a), fb = AsFeatures(b);
  FeatureOptions fo;
  Matches m = guess ? MatchGuided(fa, fb, *guess, 60.0, 0.85) : MatchFeatures(fa, fb, fo);
  if (guess && m.from.size() < size_t(o.min_inliers)) m = MatchFeatures(fa, fb, fo);
  if (m.from.size() < size_t(o.min_inliers)) return false;
  std::vector<uchar> inlier;
  const cv::Mat H = cv::findHomography(m.from, m.to, cv::RANSAC, 3.0, inlier, 2000, 0.999);
  if (H.empty()) return false;
  SupportOptions plausible;
  plausible.max_scale_change = 2.0;
  plausible.max_anisotropy = 1.5;
  plausible.max_perspective = 0.5;
  if (!IsPlausibleMotion(cv::Matx33d(H), frame, plausible)) return false;
  Edge e;
  for (size_t i = 0; i < inlier.size(); ++i)
    if (inlier[i]) {
      e.in_a.push_back(m.from[i]);
      e.in_b.push_back(m.to[i]);
    }
  if (e.in_a.size() < size_t(o.min_inliers)) return false;
  // The inliers must cover some of the frame, not one cluster.
  std::vector<cv::Point2f> hull;
  cv::convexHull(e.in_a, hull);
  if (cv::contourArea(hull) < 0.02 * frame.area()) return false;
  *out = std::move(e);
  return true;
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

}  // namespace

AlignSummary AlignStore(Store store, const AlignOptions& o, const ProgressFn& progress) {
  std::string error;
  if (!o.IsValid(&error)) Fail("align", error);
  const auto start = std::chrono::steady_clock::now();
  auto report = [&](double f) {
    if (progress) progress(std::min(1.0, f));
  };
  AlignSummary summary;
  ParallelForOptions pfo;
  pfo.threads = o.threads;

  // 1. The frames of every patch, with their stored features (or described again).
  std::map<int, PatchSidecar> sidecars;
  for (const auto& e : store.patches()) sidecars[e.id] = store.ReadSidecar(e.id);
  if (sidecars.empty()) Fail(store.dir(), "has no patches to align");
  std::vector<Node> nodes;
  std::map<FrameId, int> node_of;
  // Frames the engine followed between keyframes: not in the graph, carried along afterwards by
  // their keyframe (patch id, record, keyframe index).
  struct Followed {
    int patch = 0;
    size_t record = 0;
    int keyframe = -1;
  };
  std::vector<Followed> followed;
  cv::Size frame;
  double focal = 0;
  bool have_links = false;
  for (const auto& [id, s] : sidecars) {
    if (s.frame_size) frame = cv::Size((*s.frame_size)[0], (*s.frame_size)[1]);
    if (s.extra.contains("adjustment") && s.extra["adjustment"].contains("focal_px"))
      focal = s.extra["adjustment"]["focal_px"].get<double>();
    std::map<int, const StoredFeatures*> stored;
    std::vector<StoredFeatures> features;
    if (s.frame_features) {
      features = ReadFrameFeatures((std::filesystem::path(store.dir()) / *s.frame_features).string());
      for (const auto& f : features) stored[f.index] = &f;
    }
    have_links = have_links || s.frame_links.has_value();
    for (size_t r = 0; r < s.frames.size(); ++r) {
      if (!s.frames[r].is_keyframe()) {
        followed.push_back({id, r, s.frames[r].placed_from.value_or(-1)});
        continue;
      }
      Node n;
      n.patch = id;
      n.record = r;
      n.index = s.frames[r].index;
      n.source = s.frames[r].source;
      n.to_patch = ToMatx(s.frames[r].frame_to_patch);
      auto it = stored.find(n.index);
      if (it != stored.end()) {
        n.points = it->second->points;
        n.descriptors = it->second->descriptors.clone();
      }
      node_of[{id, n.index}] = static_cast<int>(nodes.size());
      nodes.push_back(std::move(n));
    }
  }
  const int N = static_cast<int>(nodes.size());
  summary.frames = N + static_cast<int>(followed.size());
  if (N == 0) Fail(store.dir(), "has no frames to align");
  if (frame.area() == 0) Fail(store.dir(), "its sidecars give no frame size (written by an older rolamos?)");
  if (!(focal > 0)) focal = 0.5 * frame.width / std::tan(35.0 * CV_PI / 180);  // the engine's default camera
  const cv::Matx33d K = CameraMatrix(focal, frame);
  {
    // Frames without stored features are read and described again, in parallel; not those the
    // engine chose not to describe (their ground is described by their neighbours).
    std::vector<int> missing;
    for (int i = 0; i < N; ++i) {
      const Node& n = nodes[size_t(i)];
      if (n.points.empty() && sidecars[n.patch].frames[n.record].is_described()) missing.push_back(i);
    }
    const FeatureExtractor extractor(StoredFrameFeatureOptions());
    std::atomic<int> described{0};
    ParallelFor(static_cast<long long>(missing.size()), [&](long long k, int) {
      Node& n = nodes[size_t(missing[size_t(k)])];
      const std::string path = StoredFramePath(n.source, o.frames_dir);
      if (!std::filesystem::exists(path)) return;  // no features: the frame keeps its online links only
      const Features f = DescribeStoredFrame(path, extractor);
      n.points = f.points;
      f.descriptors.convertTo(n.descriptors, CV_8U);
      ++described;
    }, pfo);
    summary.frames_described = described;
  }
  report(0.1);

  // 2. Edges the engine found: its stored links, or (older stores) the online placements of
  //    consecutive frames of a patch.
  std::vector<Edge> edges;
  std::set<std::pair<int, int>> linked;
  auto add_linked = [&](int a, int b) { linked.emplace(std::min(a, b), std::max(a, b)); };
  for (const auto& [id, s] : sidecars) {
    if (s.frame_links) {
      for (const auto& l : ReadFrameLinks((std::filesystem::path(store.dir()) / *s.frame_links).string())) {
        auto a = node_of.find(l.a), b = node_of.find(l.b);
        if (a == node_of.end() || b == node_of.end() || l.in_a.size() < 8) continue;
        Edge e;
        e.a = a->second;
        e.b = b->second;
        e.in_a = l.in_a;
        e.in_b = l.in_b;
        edges.push_back(ThinEdge(std::move(e), o.pairs_per_edge, frame));
        add_linked(a->second, b->second);
      }
    } else {
      for (size_t r = 1; r < s.frames.size(); ++r) {
        const int a = node_of[{id, s.frames[r].index}], b = node_of[{id, s.frames[r - 1].index}];
        const cv::Matx33d H = nodes[size_t(b)].to_patch.inv() * nodes[size_t(a)].to_patch;
        Edge e;
        e.a = a;
        e.b = b;
        for (int gy = 0; gy < 4; ++gy)
          for (int gx = 0; gx < 4; ++gx) {
            const cv::Point2d p((gx + 0.5) * frame.width / 4, (gy + 0.5) * frame.height / 4);
            e.in_a.emplace_back(p);
            e.in_b.emplace_back(ApplyHomography(H, p));
          }
        edges.push_back(std::move(e));
        add_linked(a, b);
      }
    }
    // A patch the engine linked to the one before by the pixel budget: its first frame's stored
    // link with the previous patch is among the links already.
  }
  summary.online_edges = static_cast<int>(edges.size());
  auto near_in_sequence = [&](int i, int j) {
    return nodes[size_t(i)].patch == nodes[size_t(j)].patch &&
           std::abs(nodes[size_t(i)].index - nodes[size_t(j)].index) < o.min_index_gap;
  };

  // 3. Appearance retrieval over every frame, each candidate verified.
  if (o.retrieval_candidates > 0) {
    std::vector<cv::Mat> descriptors;
    for (const auto& n : nodes) descriptors.push_back(n.descriptors);
    RetrievalOptions ro;
    ro.words = o.vocabulary;
    ro.candidates = o.retrieval_candidates;
    const auto candidates = RetrieveSimilarFrames(descriptors, ro, [&](int i, int j) {
      return !near_in_sequence(i, j) && !linked.count({std::min(i, j), std::max(i, j)});
    });
    summary.retrieval_tried = static_cast<int>(candidates.size());
    std::vector<Edge> found(candidates.size());
    std::vector<char> ok(candidates.size(), 0);
    ParallelFor(static_cast<long long>(candidates.size()), [&](long long k, int) {
      const auto [i, j] = candidates[size_t(k)];
      Edge e;
      if (!VerifyPair(nodes[size_t(i)], nodes[size_t(j)], nullptr, frame, o, &e)) return;
      e.a = i;
      e.b = j;
      e.kind = kRetrieval;
      found[size_t(k)] = ThinEdge(std::move(e), o.pairs_per_edge, frame);
      ok[size_t(k)] = 1;
    }, pfo);
    for (size_t k = 0; k < found.size(); ++k)
      if (ok[k]) {
        add_linked(found[k].a, found[k].b);
        edges.push_back(std::move(found[k]));
        ++summary.retrieval_edges;
      }
  }
  report(0.35);

  // 4. Components, and a first placement: within a patch the engine's own placements (already
  //    adjusted together), between patches a spanning tree of their strongest edges (the engine's
  //    links first), so that few estimates are chained.
  Components comp{static_cast<size_t>(N)};
  for (const auto& e : edges) comp.Join(e.a, e.b);
  struct PatchEdge {
    int p = 0, q = 0;
    cv::Matx33d p_to_q;
    EdgeKind kind = kOnline;
    size_t inliers = 0;
  };
  std::map<std::pair<int, int>, PatchEdge> between;  // strongest edge per pair of patches
  for (const auto& e : edges) {
    const Node& a = nodes[size_t(e.a)];
    const Node& b = nodes[size_t(e.b)];
    if (a.patch == b.patch) continue;
    // A similarity between the two patches' coordinates: chained over hundreds of patches, a
    // homography's projective terms would run away; level cameras need no more.
    std::vector<cv::Point2f> in_p, in_q;
    for (size_t i = 0; i < e.in_a.size(); ++i) {
      in_p.push_back(cv::Point2f(ApplyHomography(a.to_patch, e.in_a[i])));
      in_q.push_back(cv::Point2f(ApplyHomography(b.to_patch, e.in_b[i])));
    }
    const cv::Mat S = cv::estimateAffinePartial2D(in_p, in_q, cv::noArray(), cv::LMEDS);
    if (S.empty()) continue;
    const cv::Matx23d T(S);
    PatchEdge pe;
    pe.p = a.patch;
    pe.q = b.patch;
    pe.p_to_q = cv::Matx33d(T(0, 0), T(0, 1), T(0, 2), T(1, 0), T(1, 1), T(1, 2), 0, 0, 1);
    pe.kind = e.kind;
    pe.inliers = e.in_a.size();
    auto key = std::make_pair(std::min(pe.p, pe.q), std::max(pe.p, pe.q));
    if (pe.p > pe.q) {
      std::swap(pe.p, pe.q);
      pe.p_to_q = pe.p_to_q.inv();
    }
    auto it = between.find(key);
    if (it == between.end() || std::make_pair(-int(pe.kind), pe.inliers) > std::make_pair(-int(it->second.kind), it->second.inliers))
      between[key] = pe;
  }
  std::vector<PatchEdge> order;
  for (const auto& [key, pe] : between) order.push_back(pe);
  std::stable_sort(order.begin(), order.end(), [](const PatchEdge& x, const PatchEdge& y) {
    return x.kind != y.kind ? x.kind < y.kind : x.inliers > y.inliers;
  });
  std::map<int, int> patch_slot;
  for (const auto& [id, s] : sidecars) patch_slot[id] = static_cast<int>(patch_slot.size());
  Components patch_comp{patch_slot.size()};
  std::map<int, std::vector<std::pair<int, cv::Matx33d>>> patch_tree;  // patch -> (neighbour, this -> neighbour)
  for (const auto& pe : order)
    if (patch_comp.Join(patch_slot[pe.p], patch_slot[pe.q])) {
      patch_tree[pe.p].emplace_back(pe.q, pe.p_to_q);
      patch_tree[pe.q].emplace_back(pe.p, pe.p_to_q.inv());
    }
  std::map<int, cv::Matx33d> patch_to_plane;
  for (const auto& [id, s] : sidecars) {
    if (patch_to_plane.count(id)) continue;
    patch_to_plane[id] = cv::Matx33d::eye();
    std::vector<int> queue{id};
    for (size_t k = 0; k < queue.size(); ++k) {
      const int u = queue[k];
      for (const auto& [v, u_to_v] : patch_tree[u]) {
        if (patch_to_plane.count(v)) continue;
        cv::Matx33d G = patch_to_plane[u] * u_to_v.inv();
        G *= 1.0 / G(2, 2);
        patch_to_plane[v] = G;
        queue.push_back(v);
      }
    }
  }
  std::vector<cv::Matx33d> G(static_cast<size_t>(N));
  for (int i = 0; i < N; ++i) G[size_t(i)] = patch_to_plane[nodes[size_t(i)].patch] * nodes[size_t(i)].to_patch;
  std::map<int, std::vector<int>> members;  // root -> frames
  for (int i = 0; i < N; ++i) members[comp.Find(i)].push_back(i);
  // Each component's reference: its first frame, level, its pixels the plane's.
  for (auto& [root, list] : members) {
    const cv::Matx33d to_ref = G[size_t(root)].inv();
    for (int i : list) {
      G[size_t(i)] = to_ref * G[size_t(i)];
      G[size_t(i)] *= 1.0 / G[size_t(i)](2, 2);
    }
  }
  std::vector<PlanePose> poses(static_cast<size_t>(N));
  for (int i = 0; i < N; ++i)
    poses[size_t(i)] = comp.Find(i) == i ? ReferencePose(K) : LevelPoseFromHomography(G[size_t(i)], K, frame);

  // 5. Every component adjusted on its own (each has its own gauge), in parallel.
  PlaneAdjustmentOptions po;
  po.loss = "cauchy";
  po.loss_px = o.loss_px;
  po.per_link = true;
  po.drop_link_px = 3 * o.loss_px;
  po.max_iterations = 200;
  std::vector<char> dropped(edges.size(), 0);
  auto adjust = [&](const std::vector<GroundPrior>& priors) {
    std::vector<std::pair<int, std::vector<int>>> parts(members.begin(), members.end());
    std::atomic<int> dropped_count{0};
    ParallelFor(static_cast<long long>(parts.size()), [&](long long c, int) {
      const auto& [root, list] = parts[size_t(c)];
      if (list.size() < 2) return;
      std::map<int, int> local;
      std::vector<PlanePose> part;
      for (int i : list) {
        local[i] = static_cast<int>(part.size());
        part.push_back(poses[size_t(i)]);
      }
      std::vector<PlaneLink> links;
      std::vector<size_t> which;
      for (size_t k = 0; k < edges.size(); ++k) {
        if (dropped[k] || !local.count(edges[k].a)) continue;
        PlaneLink l;
        l.a = local[edges[k].a];
        l.b = local[edges[k].b];
        l.in_a = edges[k].in_a;
        l.in_b = edges[k].in_b;
        links.push_back(std::move(l));
        which.push_back(k);
      }
      std::vector<GroundPrior> mine;
      for (const auto& p : priors)
        if (local.count(p.frame)) {
          GroundPrior q = p;
          q.frame = local[p.frame];
          mine.push_back(q);
        }
      PlaneAdjustmentOptions opt = po;
      opt.threads = 1;
      double f = focal;
      const PlaneAdjustment r = AdjustPlanePoses(&part, &f, frame, links, local[root], {},
                                                 mine.size() >= 2 ? mine : std::vector<GroundPrior>{}, opt);
      if (!r.ok) return;  // the first placement stays
      for (size_t k = 0; k < which.size(); ++k)
        if (r.dropped[k]) {
          dropped[which[k]] = 1;
          ++dropped_count;
        }
      for (int i : list) poses[size_t(i)] = part[size_t(local[i])];
    }, pfo);
    return dropped_count.load();
  };
  auto edges_rms = [&]() {
    std::vector<PlaneLink> all;
    for (size_t k = 0; k < edges.size(); ++k) {
      if (dropped[k]) continue;
      PlaneLink l;
      l.a = edges[k].a;
      l.b = edges[k].b;
      l.in_a = edges[k].in_a;
      l.in_b = edges[k].in_b;
      all.push_back(std::move(l));
    }
    return PlaneTransferRms(poses, focal, frame, all);
  };
  summary.rms_before_px = edges_rms();
  summary.edges_dropped += adjust({});
  report(0.55);

  // 6. Loop closures: frames the solution puts over the same ground, apart in the sequence;
  //    twice, as the first ones straighten the map and bring more neighbours into view.
  for (int loop_round = 0; loop_round < 2 && o.loops_per_frame > 0; ++loop_round) {
    const int found_before = summary.loop_edges;
    std::vector<cv::Matx33d> P(static_cast<size_t>(N));
    std::vector<cv::Point2d> centre(static_cast<size_t>(N));
    for (int i = 0; i < N; ++i) {
      P[size_t(i)] = FrameToPlane(poses[size_t(i)], K);
      centre[size_t(i)] = ApplyHomography(P[size_t(i)], {(frame.width - 1) / 2.0, (frame.height - 1) / 2.0});
    }
    const double cell = std::hypot(frame.width, frame.height);
    auto key = [&](cv::Point2d c) {
      return (int64_t(std::floor(c.x / cell)) << 32) ^ uint32_t(int32_t(std::floor(c.y / cell)));
    };
    std::unordered_map<int64_t, std::vector<int>> grid;
    for (int i = 0; i < N; ++i) grid[key(centre[size_t(i)])].push_back(i);
    std::vector<std::pair<int, int>> candidates;
    for (int i = 0; i < N; ++i) {
      std::vector<std::pair<double, int>> near;
      const int cx = int(std::floor(centre[size_t(i)].x / cell)), cy = int(std::floor(centre[size_t(i)].y / cell));
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          auto it = grid.find((int64_t(cx + dx) << 32) ^ uint32_t(int32_t(cy + dy)));
          if (it == grid.end()) continue;
          for (int j : it->second) {
            if (j <= i || comp.Find(i) != comp.Find(j) || near_in_sequence(i, j) || linked.count({i, j})) continue;
            const double overlap = FootprintOverlap(P[size_t(i)], P[size_t(j)], frame);
            if (overlap >= o.loop_overlap) near.emplace_back(overlap, j);
          }
        }
      std::sort(near.rbegin(), near.rend());
      for (size_t k = 0; k < near.size() && k < size_t(o.loops_per_frame); ++k) candidates.emplace_back(i, near[k].second);
    }
    summary.loop_tried += static_cast<int>(candidates.size());
    std::vector<Edge> found(candidates.size());
    std::vector<char> ok(candidates.size(), 0);
    ParallelFor(static_cast<long long>(candidates.size()), [&](long long k, int) {
      const auto [i, j] = candidates[size_t(k)];
      const cv::Matx33d guess = P[size_t(j)].inv() * P[size_t(i)];
      Edge e;
      if (!VerifyPair(nodes[size_t(i)], nodes[size_t(j)], &guess, frame, o, &e)) return;
      e.a = i;
      e.b = j;
      e.kind = kLoop;
      found[size_t(k)] = ThinEdge(std::move(e), o.pairs_per_edge, frame);
      ok[size_t(k)] = 1;
    }, pfo);
    for (size_t k = 0; k < found.size(); ++k)
      if (ok[k]) {
        add_linked(found[k].a, found[k].b);
        edges.push_back(std::move(found[k]));
        dropped.push_back(0);
        ++summary.loop_edges;
      }
    if (summary.loop_edges == found_before) break;
    summary.edges_dropped += adjust({});
    report(0.6 + 0.1 * loop_round);
  }
  report(0.8);

  // 7. Navigation: the centres pulled towards it, through the similarity that carries the plane
  //    to the map (refitted as the solution moves).
  // Each followed frame goes with the keyframe it was followed from (or the patch's nearest).
  std::vector<int> followed_node(followed.size(), -1);
  std::map<int, int> extra_frames;  // root -> followed frames in its component
  for (size_t k = 0; k < followed.size(); ++k) {
    const Followed& f = followed[k];
    auto it = node_of.find({f.patch, f.keyframe});
    if (it == node_of.end()) {
      const int index = sidecars[f.patch].frames[f.record].index;
      int best = -1;
      for (const auto& [id, i] : node_of)
        if (id.patch == f.patch && (best < 0 || std::abs(id.index - index) < std::abs(nodes[size_t(best)].index - index)))
          best = i;
      followed_node[k] = best;
    } else {
      followed_node[k] = it->second;
    }
    if (followed_node[k] >= 0) ++extra_frames[comp.Find(followed_node[k])];
  }
  // Each navigated frame: the node it pulls (itself, or the keyframe a followed frame goes with),
  // its centre in that node's pixels, and the map position of its centre.
  struct NavPoint {
    int node = 0;
    cv::Point2d pixel, map;
  };
  std::vector<NavPoint> nav_points;
  std::string nav_crs;
  const cv::Point2d frame_centre((frame.width - 1) / 2.0, (frame.height - 1) / 2.0);
  if (!o.navigation.empty()) {
    auto add = [&](const std::string& source, int node, cv::Point2d pixel) {
      const FrameNavigation* n = FindFrameNavigation(o.navigation, source);
      if (!n) return;
      const auto& g = n->geotransform;
      const double c = frame_centre.x, r = frame_centre.y;
      nav_points.push_back({node, pixel, cv::Point2d(g[0] + (c + 0.5) * g[1] + (r + 0.5) * g[2],
                                                     g[3] + (c + 0.5) * g[4] + (r + 0.5) * g[5])});
      nav_crs = n->crs;
    };
    for (int i = 0; i < N; ++i) add(nodes[size_t(i)].source, i, frame_centre);
    for (size_t k = 0; k < followed.size(); ++k) {
      const int i = followed_node[k];
      if (i < 0) continue;
      const FrameRecord& f = sidecars[followed[k].patch].frames[followed[k].record];
      add(f.source, i, ApplyHomography(nodes[size_t(i)].to_patch.inv() * ToMatx(f.frame_to_patch), frame_centre));
    }
    summary.navigation_frames = static_cast<int>(nav_points.size());
    if (nav_points.empty())
      Fail("navigation", "none of its " + std::to_string(o.navigation.size()) +
                             " frames is a frame of this store (frames are matched by file name)");
  }
  auto nav_residual = [&](cv::Matx33d* to_map) {
    std::vector<cv::Point2d> from, to;
    for (const auto& p : nav_points) {
      from.push_back(ApplyHomography(FrameToPlane(poses[size_t(p.node)], K), p.pixel));
      to.push_back(p.map);
    }
    const auto S = FitSimilarity(from, to);
    if (!S) return -1.0;
    *to_map = *S;
    std::vector<double> d;
    for (size_t k = 0; k < from.size(); ++k) d.push_back(cv::norm(ApplyHomography(*S, from[k]) - to[k]));
    return Median(d);
  };
  if (nav_points.size() >= 2) {
    cv::Matx33d to_map;
    summary.navigation_before_m = nav_residual(&to_map);
    for (int round = 0; round < 2 && summary.navigation_before_m >= 0; ++round) {
      const cv::Matx33d from_map = to_map.inv();
      const double metres_per_px = std::sqrt(std::abs(to_map(0, 0) * to_map(1, 1) - to_map(0, 1) * to_map(1, 0)));
      std::vector<GroundPrior> priors;
      for (const auto& n : nav_points) {
        GroundPrior p;
        p.frame = n.node;
        p.pixel = n.pixel;
        p.xy = ApplyHomography(from_map, n.map);
        p.sigma_px = o.navigation_sigma_m / std::max(1e-12, metres_per_px);
        priors.push_back(p);
      }
      summary.edges_dropped += adjust(priors);
      summary.navigation_after_m = nav_residual(&to_map);
    }
  }
  summary.rms_after_px = edges_rms();

  // 8. Components side by side (largest first, left to right), each frame's placement, and each
  //    patch's best-fit placement and component.
  std::vector<std::pair<int, int>> by_size;  // (frames, root)
  for (const auto& [root, list] : members)
    by_size.emplace_back(static_cast<int>(list.size()) + extra_frames[root], root);
  std::sort(by_size.begin(), by_size.end(), [](const auto& x, const auto& y) {
    return x.first != y.first ? x.first > y.first : x.second < y.second;
  });
  std::map<int, int> component_of_root;
  std::map<int, cv::Matx33d> shift;  // root -> plane to global
  double next_x = 0;
  for (size_t c = 0; c < by_size.size(); ++c) {
    const int root = by_size[c].second;
    component_of_root[root] = static_cast<int>(c);
    summary.component_frames.push_back(by_size[c].first);
    cv::Rect2d box;
    for (int i : members[root]) {
      const cv::Rect2d b = WarpedBounds(FrameToPlane(poses[size_t(i)], K), frame);
      box = box.area() > 0 ? (box | b) : b;
    }
    // The largest component keeps its coordinates (navigation, if any, fitted to it); the others
    // follow to its right, a frame's width apart.
    if (c == 0) {
      shift[root] = cv::Matx33d::eye();
      next_x = box.x + box.width + frame.width;
    } else {
      shift[root] = cv::Matx33d(1, 0, next_x - box.x, 0, 1, -box.y, 0, 0, 1);
      next_x += box.width + frame.width;
    }
  }
  summary.components = static_cast<int>(by_size.size());
  std::map<int, std::vector<cv::Point2d>> patch_pts, global_pts;
  std::map<int, std::map<int, int>> patch_components;
  for (int i = 0; i < N; ++i) {
    const Node& n = nodes[size_t(i)];
    const int root = comp.Find(i);
    const cv::Matx33d to_global = shift[root] * FrameToPlane(poses[size_t(i)], K);
    PatchSidecar& s = sidecars[n.patch];
    s.frames[n.record].frame_to_global = ToArray9(to_global);
    ++patch_components[n.patch][component_of_root[root]];
    for (int gy = 0; gy < 3; ++gy)
      for (int gx = 0; gx < 3; ++gx) {
        const cv::Point2d p(gx * (frame.width - 1) / 2.0, gy * (frame.height - 1) / 2.0);
        patch_pts[n.patch].push_back(ApplyHomography(n.to_patch, p));
        global_pts[n.patch].push_back(ApplyHomography(to_global, p));
      }
  }
  for (size_t k = 0; k < followed.size(); ++k) {
    const int i = followed_node[k];
    if (i < 0) continue;
    const Node& key = nodes[size_t(i)];
    PatchSidecar& s = sidecars[followed[k].patch];
    FrameRecord& f = s.frames[followed[k].record];
    const cv::Matx33d key_to_global = ToMatx(*sidecars[key.patch].frames[key.record].frame_to_global);
    f.frame_to_global = ToArray9(key_to_global * key.to_patch.inv() * ToMatx(f.frame_to_patch));
  }
  std::vector<PatchSidecar> updated;
  for (auto& [id, s] : sidecars) {
    if (s.patch_to_global && !s.patch_to_global_online) s.patch_to_global_online = *s.patch_to_global;
    const cv::Mat H = cv::findHomography(patch_pts[id], global_pts[id], 0);
    if (H.empty()) Fail(store.PatchSidecarPath(id), "its frames give no patch placement");
    s.patch_to_global = ToArray9(cv::Matx33d(H));
    s.aligned = true;
    int best = 0, count = -1;
    for (const auto& [c, k] : patch_components[id])
      if (k > count) best = c, count = k;
    s.component = best;
    updated.push_back(s);
  }
  GlobalRecord global = store.global();
  store.ReplaceSidecars(updated, global);
  report(1.0);
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

}  // namespace rolamos

#include "align/frame_graph.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <filesystem>
#include <functional>
#include <numeric>
#include <tuple>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "align/retrieval.h"
#include "align/stored_frames.h"
#include "engine/patch_adjustment.h"
#include "engine/registration.h"
#include "geometry/pair_compression.h"
#include "geometry/plane_adjustment.h"
#include "rolamos/error.hpp"
#include "util/homography.h"

namespace rolamos {

UnionFind::UnionFind(size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0); }

int UnionFind::Find(int i) {
  while (parent[size_t(i)] != i) i = parent[size_t(i)] = parent[size_t(parent[size_t(i)])];
  return i;
}

bool UnionFind::Join(int a, int b) {
  a = Find(a), b = Find(b);
  if (a == b) return false;
  parent[size_t(std::max(a, b))] = std::min(a, b);
  return true;
}

GraphEdge ThinEdge(GraphEdge e, int n, cv::Size frame) {
  FrameLink l{e.a, e.b, e.in_a, e.in_b};
  l = Thin(std::move(l), n, frame);
  e.in_a = std::move(l.in_a);
  e.in_b = std::move(l.in_b);
  return e;
}

GraphEdge CompressEdge(GraphEdge e, int points, double loss_px) {
  CompressedPairs c;
  if (!e.weight.empty() || !CompressPairs(e.in_a, e.in_b, points, &c, loss_px)) return e;
  e.in_a = std::move(c.in_a);
  e.in_b = std::move(c.in_b);
  e.weight = std::move(c.weight);
  e.scatter_px = static_cast<float>(c.scatter_px);
  e.matches = c.pairs;
  return e;
}

GraphEdge MeasureEdge(GraphEdge e, const AlignOptions& o, cv::Size frame) {
  return CompressEdge(ThinEdge(std::move(e), o.pairs_per_edge, frame), o.points_per_edge, o.edge_loss_px);
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

namespace {

// The node's primary features, or all of them.
Features AsFeatures(const GraphNode& n, bool all = false) {
  const int size = static_cast<int>(n.points.size());
  const int count = all || n.primary <= 0 ? size : std::min(n.primary, size);
  Features f;
  f.points.assign(n.points.begin(), n.points.begin() + count);
  // The stored bytes as they are (SIFT's whole numbers: matched to the same distances as floats).
  if (count > 0) f.descriptors = n.descriptors.rowRange(0, count);
  f.norm = cv::NORM_L2;
  return f;
}

// Stage 1: the keyframes of every patch with their stored features; followed frames aside.
void LoadNodes(const Store& store, FrameGraph& g, const ParallelForOptions& pfo) {
  // Each patch's sidecar and stored features read on every core (JSON and files: on 10,000
  // frames a third of the graph's time on one core), then taken in the patches' order.
  const std::vector<PatchEntry> entries = store.patches();
  if (entries.empty()) Fail(store.dir(), "has no patches to align");
  std::vector<PatchSidecar> sidecars(entries.size());
  std::vector<std::vector<StoredFeatures>> features(entries.size());
  ParallelFor(static_cast<long long>(entries.size()), [&](long long k, int) {
    sidecars[size_t(k)] = store.ReadSidecar(entries[size_t(k)].id);
    if (sidecars[size_t(k)].frame_features)
      features[size_t(k)] =
          ReadFrameFeatures((std::filesystem::path(store.dir()) / *sidecars[size_t(k)].frame_features).string());
  }, pfo);
  std::map<int, size_t> order;  // patch id -> entry, taken in the order of ids
  for (size_t k = 0; k < entries.size(); ++k) order[entries[k].id] = k;
  for (const auto& [id, k] : order) g.sidecars[id] = std::move(sidecars[k]);
  // The patches' focal lengths, each estimated with its poses (or the one camera's): their median.
  std::vector<double> focals;
  for (const auto& [id, s] : g.sidecars) {
    if (s.frame_size) g.frame = cv::Size((*s.frame_size)[0], (*s.frame_size)[1]);
    if (s.extra.contains("adjustment") && s.extra["adjustment"].contains("focal_px"))
      focals.push_back(s.extra["adjustment"]["focal_px"].get<double>());
    std::map<int, StoredFeatures*> stored;
    for (auto& f : features[order.at(id)]) stored[f.index] = &f;
    for (size_t r = 0; r < s.frames.size(); ++r) {
      if (!s.frames[r].is_keyframe()) {
        g.followed.push_back({id, r, s.frames[r].placed_from.value_or(-1)});
        continue;
      }
      GraphNode n;
      n.patch = id;
      n.record = r;
      n.index = s.frames[r].index;
      n.source = s.frames[r].source;
      n.to_patch = ToMatx(s.frames[r].frame_to_patch);
      auto it = stored.find(n.index);
      if (it != stored.end()) {
        n.points = std::move(it->second->points);
        n.descriptors = it->second->descriptors;  // each frame's own buffer, read for it
        n.primary = std::min<int>(static_cast<int>(n.points.size()), kPrimaryStoredFeatures);
      }
      g.node_of[{id, n.index}] = g.size();
      g.nodes.push_back(std::move(n));
    }
  }
  if (!focals.empty()) {
    std::nth_element(focals.begin(), focals.begin() + long(focals.size() / 2), focals.end());
    g.focal = focals[focals.size() / 2];
  }
  if (g.nodes.empty()) Fail(store.dir(), "has no frames to align");
  if (g.frame.area() == 0) Fail(store.dir(), "its sidecars give no frame size (written by an older rolamos?)");
  if (!(g.focal > 0)) g.focal = 0.5 * g.frame.width / std::tan(35.0 * CV_PI / 180);  // the engine's default camera
  g.K = CameraMatrix(g.focal, g.frame);
}

// Frames without stored features are read and described again, in parallel; not those the engine
// chose not to describe (their ground is described by their neighbours).
int DescribeMissing(FrameGraph& g, const AlignOptions& o, const ParallelForOptions& pfo) {
  std::vector<int> missing;
  for (int i = 0; i < g.size(); ++i) {
    const GraphNode& n = g.nodes[size_t(i)];
    if (n.points.empty() && g.sidecars[n.patch].frames[n.record].is_described()) missing.push_back(i);
  }
  const FeatureExtractor extractor(StoredFrameFeatureOptions());
  std::atomic<int> described{0};
  ParallelFor(static_cast<long long>(missing.size()), [&](long long k, int) {
    GraphNode& n = g.nodes[size_t(missing[size_t(k)])];
    const std::string path = StoredFramePath(n.source, o.frames_dir);
    if (!std::filesystem::exists(path)) return;  // no features: the frame keeps its online links only
    const Features f = DescribeStoredFrame(path, extractor);
    n.points = f.points;
    f.descriptors.convertTo(n.descriptors, CV_8U);
    n.primary = 0;  // all
    ++described;
  }, pfo);
  return described;
}

// Stage 2: the engine's stored links, or (older stores) the online placements of consecutive
// frames of a patch.
void AddOnlineEdges(const Store& store, const AlignOptions& o, FrameGraph& g, const ParallelForOptions& pfo) {
  std::vector<size_t> stored;  // the stored links' edges, measured together below (on every core)
  for (const auto& [id, s] : g.sidecars) {
    if (s.frame_links) {
      for (const auto& l : ReadFrameLinks((std::filesystem::path(store.dir()) / *s.frame_links).string())) {
        auto a = g.node_of.find(l.a), b = g.node_of.find(l.b);
        if (a == g.node_of.end() || b == g.node_of.end() || l.in_a.size() < 8) continue;
        GraphEdge e;
        e.a = a->second;
        e.b = b->second;
        e.in_a = l.in_a;
        e.in_b = l.in_b;
        stored.push_back(g.edges.size());
        g.edges.push_back(std::move(e));
        g.AddLinked(a->second, b->second);
      }
    } else {
      for (size_t r = 1; r < s.frames.size(); ++r) {
        const int a = g.node_of[{id, s.frames[r].index}], b = g.node_of[{id, s.frames[r - 1].index}];
        const cv::Matx33d H = g.nodes[size_t(b)].to_patch.inv() * g.nodes[size_t(a)].to_patch;
        GraphEdge e;
        e.a = a;
        e.b = b;
        for (int gy = 0; gy < 4; ++gy)
          for (int gx = 0; gx < 4; ++gx) {
            const cv::Point2d p((gx + 0.5) * g.frame.width / 4, (gy + 0.5) * g.frame.height / 4);
            e.in_a.emplace_back(p);
            e.in_b.emplace_back(ApplyHomography(H, p));
          }
        g.edges.push_back(std::move(e));
        g.AddLinked(a, b);
      }
    }
    // A patch the engine linked to the one before by the pixel budget: its first frame's stored
    // link with the previous patch is among the links already.
  }
  ParallelFor(static_cast<long long>(stored.size()), [&](long long k, int) {
    GraphEdge& e = g.edges[stored[size_t(k)]];
    e = MeasureEdge(std::move(e), o, g.frame);
  }, pfo);
}

}  // namespace

FrameGraph LoadFrameGraph(const Store& store, const AlignOptions& o, AlignSummary* summary, const ParallelForOptions& pfo) {
  FrameGraph g;
  LoadNodes(store, g, pfo);
  summary->frames = g.size() + static_cast<int>(g.followed.size());
  summary->frames_described = DescribeMissing(g, o, pfo);
  AddOnlineEdges(store, o, g, pfo);
  summary->online_edges = static_cast<int>(g.edges.size());
  return g;
}

namespace {

// Retrieval's candidates that `allowed` lets through, verified, added as appearance edges;
// returns (tried, added).
std::pair<int, int> AddAppearanceEdges(FrameGraph& g, const AlignOptions& o, int candidates_per_frame,
                                       const std::function<bool(int, int)>& allowed, const ParallelForOptions& pfo) {
  if (g.appearance.empty()) {
    std::vector<cv::Mat> descriptors;
    for (const auto& n : g.nodes)
      descriptors.push_back(n.primary > 0 && n.primary < n.descriptors.rows ? n.descriptors.rowRange(0, n.primary)
                                                                             : n.descriptors);
    RetrievalOptions ro;
    ro.words = o.vocabulary;
    g.appearance = DescribeFrames(descriptors, ro);
  }
  const auto candidates = MostSimilarPairs(g.appearance, candidates_per_frame, allowed);
  std::vector<GraphEdge> found(candidates.size());
  std::vector<char> ok(candidates.size(), 0);
  ParallelFor(static_cast<long long>(candidates.size()), [&](long long k, int) {
    const auto [i, j] = candidates[size_t(k)];
    GraphEdge e;
    if (!VerifyPair(g.nodes[size_t(i)], g.nodes[size_t(j)], nullptr, g.frame, o, &e)) return;
    e.a = i;
    e.b = j;
    e.kind = kRetrieval;
    found[size_t(k)] = MeasureEdge(std::move(e), o, g.frame);
    ok[size_t(k)] = 1;
  }, pfo);
  int added = 0;
  for (size_t k = 0; k < found.size(); ++k)
    if (ok[k]) {
      g.AddLinked(found[k].a, found[k].b);
      g.edges.push_back(std::move(found[k]));
      ++added;
    }
  return {static_cast<int>(candidates.size()), added};
}

}  // namespace

void AddRetrievalEdges(FrameGraph& g, const AlignOptions& o, AlignSummary* summary, const ParallelForOptions& pfo) {
  if (o.retrieval_candidates <= 0) return;
  std::tie(summary->retrieval_tried, summary->retrieval_edges) =
      AddAppearanceEdges(g, o, o.retrieval_candidates, [&](int i, int j) {
        return !g.NearInSequence(i, j, o.min_index_gap) && !g.Linked(i, j);
      }, pfo);
}

void AddRejoiningEdges(FrameGraph& g, const AlignOptions& o, AlignSummary* summary, const ParallelForOptions& pfo) {
  if (o.rejoin_candidates <= 0 || o.retrieval_candidates <= 0) return;
  UnionFind parts(g.nodes.size());
  int count = g.size();
  for (const auto& e : g.edges) count -= parts.Join(e.a, e.b) ? 1 : 0;
  if (count <= 1) return;
  // Each frame's part, found once: the search asks from several threads (Find compresses paths).
  std::vector<int> part(g.nodes.size());
  for (size_t i = 0; i < part.size(); ++i) part[i] = parts.Find(static_cast<int>(i));
  AlignOptions relaxed = o;
  relaxed.min_inliers = std::min(o.min_inliers, o.rejoin_min_inliers);
  std::tie(summary->rejoin_tried, summary->rejoin_edges) =
      AddAppearanceEdges(g, relaxed, o.rejoin_candidates, [&](int i, int j) {
        return part[size_t(i)] != part[size_t(j)] && !g.Linked(i, j);
      }, pfo);
}

namespace {

// Pairs whose primary features give fewer matches than this (ratio test and mutual) share no
// ground worth matching all the features for. 10 keeps every link the second tier found on
// five surveys (degraded, light-cone, 984 stills) for a third less of align's CPU on 984 stills,
// and 40 % less where lanes share no ground; at 15 or 20 degraded lanes lose links
// (bench/RESULTS.md, session 42).
constexpr size_t kSecondTierMatches = 10;

// The pairs of `m` that a RANSAC homography fits, when they are enough, the homography is one a
// camera over the seafloor makes, and they cover some of the frame (not one cluster). `seen`:
// the most matches any call was given.
bool VerifyMatches(Matches m, cv::Size frame, const AlignOptions& o, GraphEdge* out, size_t* seen) {
  *seen = std::max(*seen, m.from.size());
  const VerifiedMatch v = VerifyByHomography(std::move(m), o.min_inliers);
  if (!v.inliers) return false;
  SupportOptions plausible;
  plausible.max_scale_change = 2.0;
  plausible.max_anisotropy = 1.5;
  plausible.max_perspective = 0.5;
  if (!IsPlausibleMotion(v.H, frame, plausible)) return false;
  GraphEdge e;
  v.Inliers(&e.in_a, &e.in_b);
  std::vector<cv::Point2f> hull;
  cv::convexHull(e.in_a, hull);
  if (cv::contourArea(hull) < 0.02 * frame.area()) return false;
  *out = std::move(e);
  return true;
}

}  // namespace

bool VerifyPair(const GraphNode& a, const GraphNode& b, const cv::Matx33d* guess, cv::Size frame, const AlignOptions& o,
                GraphEdge* out) {
  if (a.points.size() < size_t(o.min_inliers) || b.points.size() < size_t(o.min_inliers)) return false;
  // Guided by where the frames are, then over all their features: the guess may be further off
  // than the guided search reaches (a degraded survey's lanes drift 100 px and more apart), and
  // then its matches are many and wrong. The primary features first, then all, where the
  // primary ones gave some matches.
  const auto has_more = [](const GraphNode& n) { return n.primary > 0 && n.points.size() > size_t(n.primary); };
  const bool more = has_more(a) || has_more(b);
  size_t seen = 0;  // the most matches the primary features gave
  for (bool all : {false, true}) {
    if (all && (!more || seen < kSecondTierMatches)) break;
    const Features fa = AsFeatures(a, all), fb = AsFeatures(b, all);
    if (guess && VerifyMatches(MatchGuided(fa, fb, *guess, 60.0, 0.85), frame, o, out, &seen)) return true;
    if (VerifyMatches(MatchFeatures(fa, fb, FeatureOptions()), frame, o, out, &seen)) return true;
  }
  return false;
}

}  // namespace rolamos

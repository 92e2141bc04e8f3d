#include "objects/box_evaluation.h"

#include <algorithm>
#include <cmath>
#include <map>

#include "objects/window_search.h"

namespace rolamos {

namespace {

constexpr double kMatchIou = 0.5;

struct Ranked {
  double score;
  bool true_positive;
};

// Every detection, best first, with whether it found a box no better detection found (each true
// box is matched once, to the unmatched box it overlaps most).
std::vector<Ranked> Rank(const std::vector<std::vector<BoxDetection>>& detections,
                         const std::vector<std::vector<cv::Rect2d>>& truth) {
  struct Item {
    double score;
    size_t image, index;
  };
  std::vector<Item> items;
  for (size_t i = 0; i < detections.size(); ++i)
    for (size_t k = 0; k < detections[i].size(); ++k) items.push_back({detections[i][k].score, i, k});
  std::stable_sort(items.begin(), items.end(), [](const Item& a, const Item& b) { return a.score > b.score; });
  std::vector<std::vector<bool>> taken(truth.size());
  for (size_t i = 0; i < truth.size(); ++i) taken[i].assign(truth[i].size(), false);
  std::vector<Ranked> out;
  for (const Item& it : items) {
    const cv::Rect2d& box = detections[it.image][it.index].box;
    double best = kMatchIou;
    int match = -1;
    const auto& gt = it.image < truth.size() ? truth[it.image] : std::vector<cv::Rect2d>{};
    for (size_t g = 0; g < gt.size(); ++g) {
      const double iou = BoxIou(box, gt[g]);
      if (!taken[it.image][g] && iou >= best) {
        best = iou;
        match = static_cast<int>(g);
      }
    }
    if (match >= 0) taken[it.image][static_cast<size_t>(match)] = true;
    out.push_back({it.score, match >= 0});
  }
  return out;
}

long long CountBoxes(const std::vector<std::vector<cv::Rect2d>>& truth) {
  long long n = 0;
  for (const auto& t : truth) n += static_cast<long long>(t.size());
  return n;
}

}  // namespace

std::vector<BoxDetection> SuppressBoxes(std::vector<BoxDetection> d, double iou, double containment) {
  std::stable_sort(d.begin(), d.end(), [](const BoxDetection& a, const BoxDetection& b) { return a.score > b.score; });
  // Kept boxes are filed in a grid of buckets, so a candidate is compared with its neighbours only.
  double side = 16;
  for (const auto& b : d) side = std::max(side, std::max(b.box.width, b.box.height));
  std::map<std::pair<long long, long long>, std::vector<size_t>> buckets;
  auto span = [&](const cv::Rect2d& r, long long* x0, long long* y0, long long* x1, long long* y1) {
    *x0 = static_cast<long long>(std::floor(r.x / side));
    *y0 = static_cast<long long>(std::floor(r.y / side));
    *x1 = static_cast<long long>(std::floor((r.x + r.width) / side));
    *y1 = static_cast<long long>(std::floor((r.y + r.height) / side));
  };
  std::vector<BoxDetection> kept;
  for (auto& c : d) {
    long long x0, y0, x1, y1;
    span(c.box, &x0, &y0, &x1, &y1);
    bool overlapped = false;
    for (long long y = y0; y <= y1 && !overlapped; ++y)
      for (long long x = x0; x <= x1 && !overlapped; ++x) {
        const auto it = buckets.find({x, y});
        if (it == buckets.end()) continue;
        for (size_t k : it->second) {
          const double inter = (kept[k].box & c.box).area();
          const double smaller = std::min(kept[k].box.area(), c.box.area());
          if (BoxIou(kept[k].box, c.box) > iou || (smaller > 0 && inter / smaller > containment)) {
            overlapped = true;
            break;
          }
        }
      }
    if (overlapped) continue;
    for (long long y = y0; y <= y1; ++y)
      for (long long x = x0; x <= x1; ++x) buckets[{x, y}].push_back(kept.size());
    kept.push_back(c);
  }
  return kept;
}

BoxEvaluation EvaluateBoxes(const std::vector<std::vector<BoxDetection>>& detections,
                            const std::vector<std::vector<cv::Rect2d>>& truth, double threshold) {
  BoxEvaluation e;
  e.threshold = threshold;
  e.images = static_cast<int>(truth.size());
  e.true_boxes = CountBoxes(truth);
  const std::vector<Ranked> ranked = Rank(detections, truth);
  // All-point interpolated AP: the area under the precision envelope.
  std::vector<double> precision, recall;
  long long tp = 0;
  for (size_t i = 0; i < ranked.size(); ++i) {
    tp += ranked[i].true_positive ? 1 : 0;
    precision.push_back(double(tp) / double(i + 1));
    recall.push_back(e.true_boxes > 0 ? double(tp) / double(e.true_boxes) : 0);
    if (ranked[i].score >= threshold) {
      e.detections = static_cast<long long>(i + 1);
      e.true_positives = tp;
    }
  }
  for (size_t i = precision.size(); i-- > 1;) precision[i - 1] = std::max(precision[i - 1], precision[i]);
  double last = 0;
  for (size_t i = 0; i < precision.size(); ++i) {
    e.ap50 += (recall[i] - last) * precision[i];
    last = recall[i];
  }
  e.precision = e.detections > 0 ? double(e.true_positives) / double(e.detections) : 0;
  e.recall = e.true_boxes > 0 ? double(e.true_positives) / double(e.true_boxes) : 0;
  e.f1 = e.precision + e.recall > 0 ? 2 * e.precision * e.recall / (e.precision + e.recall) : 0;
  return e;
}

double BestF1Threshold(const std::vector<std::vector<BoxDetection>>& detections,
                       const std::vector<std::vector<cv::Rect2d>>& truth) {
  const std::vector<Ranked> ranked = Rank(detections, truth);
  const long long boxes = CountBoxes(truth);
  double best_f1 = -1, best = 0;
  long long tp = 0;
  for (size_t i = 0; i < ranked.size(); ++i) {
    tp += ranked[i].true_positive ? 1 : 0;
    // Only where the next detection scores lower: a threshold cannot split equal scores.
    if (i + 1 < ranked.size() && ranked[i + 1].score == ranked[i].score) continue;
    const double f1 = boxes > 0 ? 2.0 * double(tp) / double(static_cast<long long>(i + 1) + boxes) : 0;
    if (f1 > best_f1) {
      best_f1 = f1;
      best = ranked[i].score;
    }
  }
  return best;
}

nlohmann::json ToJson(const BoxEvaluation& e) {
  return {{"ap50", e.ap50},         {"precision", e.precision},   {"recall", e.recall},
          {"f1", e.f1},             {"threshold", e.threshold},   {"true_boxes", e.true_boxes},
          {"detections", e.detections}, {"true_positives", e.true_positives}, {"images", e.images}};
}

}  // namespace rolamos

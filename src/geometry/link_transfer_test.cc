#include "geometry/link_transfer.h"

#include <cmath>
#include <memory>
#include <random>
#include <vector>

#include <ceres/ceres.h>
#include <gtest/gtest.h>

namespace rolamos {
namespace {

// The reference: each pixel cast onto the plane and seen by b one at a time, in Ceres's jets
// (how the adjustment computed its links before LinkTransferCost).
struct JetTransfer {
  const PlaneLink* l;
  double cx, cy, knee;
  bool cauchy;
  template <typename T>
  bool operator()(const T* ea, const T* ca, const T* eb, const T* cb, const T* f, T* r) const {
    T Ra[9], Rb[9];
    PlaneRotation(ea, Ra);
    PlaneRotation(eb, Rb);
    for (size_t i = 0; i < l->in_a.size(); ++i) {
      const cv::Point2f pa = l->in_a[i], pb = l->in_b[i];
      const T v[3] = {(T(pa.x) - T(cx)) / f[0], (T(pa.y) - T(cy)) / f[0], T(1)};
      T d[3];
      for (int k = 0; k < 3; ++k) d[k] = Ra[k] * v[0] + Ra[3 + k] * v[1] + Ra[6 + k] * v[2];
      if (!(d[2] > T(1e-6))) return false;
      const T s = -ca[2] / d[2];
      const T X[3] = {ca[0] + s * d[0] - cb[0], ca[1] + s * d[1] - cb[1], -cb[2]};
      T c[3];
      for (int k = 0; k < 3; ++k) c[k] = Rb[3 * k] * X[0] + Rb[3 * k + 1] * X[1] + Rb[3 * k + 2] * X[2];
      if (!(c[2] > T(1e-6))) return false;
      const double w = LinkWeight(*l) * PairWeight(*l, i);
      T* ri = r + 2 * i;
      ri[0] = T(w) * (f[0] * c[0] / c[2] + T(cx) - T(pb.x));
      ri[1] = T(w) * (f[0] * c[1] / c[2] + T(cy) - T(pb.y));
      if (!(knee > 0)) continue;
      const double a = knee * PairWeight(*l, i), a2 = a * a;
      const T sq = ri[0] * ri[0] + ri[1] * ri[1];
      T scale;
      if (cauchy) {
        if (!(sq > T(1e-12 * a2))) continue;
        scale = sqrt(T(a2) * log(T(1) + sq / T(a2)) / sq);
      } else {
        if (!(sq > T(a2))) continue;
        const T norm = sqrt(sq);
        scale = sqrt(T(2 * a) * norm - T(a2)) / norm;
      }
      ri[0] *= scale;
      ri[1] *= scale;
    }
    return true;
  }
};

// Pixels of a matched where the poses `params` put them in b, with a pixel of noise, and every
// fifth far off (the robust loss's two sides).
PlaneLink NoisyLink(std::mt19937& rng, bool weighted, const double* const* params, double cx, double cy) {
  PlaneLink l;
  std::uniform_real_distribution<float> px(0, 400), py(0, 300);
  for (int i = 0; i < 40; ++i) {
    const cv::Point2f p(px(rng), py(rng));
    l.in_a.push_back(p);
    if (weighted) l.pair_weight.push_back(0.5f + float(i % 3));
  }
  l.in_b = l.in_a;
  std::vector<double> r(2 * l.in_a.size());
  PlaneLink unweighted = l;
  unweighted.pair_weight.clear();
  EXPECT_TRUE(LinkTransferCost(&unweighted, cx, cy).Evaluate(params, r.data(), nullptr));
  std::normal_distribution<float> noise(0, 1);
  for (size_t i = 0; i < l.in_b.size(); ++i) {
    const float far = i % 5 == 0 ? 10.f : 1.f;
    l.in_b[i] += cv::Point2f(float(r[2 * i]) + noise(rng) * far, float(r[2 * i + 1]) + noise(rng) * far);
  }
  l.weight = 0.7;
  return l;
}

struct Case {
  double knee;
  bool cauchy, trusted, weighted;
};

TEST(LinkTransferCost, MatchesThePixelByPixelJetsInResidualsAndJacobians) {
  std::mt19937 rng(7);
  const double cx = 199.5, cy = 149.5;
  // yaw, pitch, roll; centre; of a, then of b; focal length.
  double ea[3] = {0.3, 0.04, -0.03}, ca[3] = {100, 50, -10}, eb[3] = {0.35, -0.02, 0.05}, cb[3] = {101.4, 50.3, -10.2};
  double f = 400;
  const double* params[5] = {ea, ca, eb, cb, &f};
  for (const Case c : {Case{0, false, false, false}, Case{1.5, false, false, true}, Case{1.5, true, false, true},
                       Case{0, false, true, true}, Case{3, false, false, false}}) {
    PlaneLink l = NoisyLink(rng, c.weighted, params, cx, cy);
    l.trusted = c.trusted;
    const int n = 2 * static_cast<int>(l.in_a.size());
    LinkTransferCost ours(&l, cx, cy, c.knee, c.cauchy);
    ceres::AutoDiffCostFunction<JetTransfer, ceres::DYNAMIC, 3, 3, 3, 3, 1> theirs(
        new JetTransfer{&l, cx, cy, c.knee, c.cauchy}, n);
    ASSERT_EQ(ours.num_residuals(), n);
    std::vector<double> r_ours(static_cast<size_t>(n)), r_theirs(static_cast<size_t>(n));
    const int sizes[5] = {3, 3, 3, 3, 1};
    std::vector<std::vector<double>> j_ours(5), j_theirs(5);
    double* jo[5];
    double* jt[5];
    for (int b = 0; b < 5; ++b) {
      j_ours[size_t(b)].assign(size_t(n * sizes[b]), 0);
      j_theirs[size_t(b)].assign(size_t(n * sizes[b]), 0);
      jo[b] = j_ours[size_t(b)].data();
      jt[b] = j_theirs[size_t(b)].data();
    }
    jo[4] = nullptr;  // a constant block (the focal length held): not asked for
    jt[4] = nullptr;
    ASSERT_TRUE(ours.Evaluate(params, r_ours.data(), jo));
    ASSERT_TRUE(theirs.Evaluate(params, r_theirs.data(), jt));
    int discounted = 0;
    for (int i = 0; i < n; ++i) EXPECT_NEAR(r_ours[size_t(i)], r_theirs[size_t(i)], 1e-9 * (1 + std::abs(r_theirs[size_t(i)])));
    for (int b = 0; b < 4; ++b)
      for (size_t k = 0; k < j_ours[size_t(b)].size(); ++k)
        EXPECT_NEAR(j_ours[size_t(b)][k], j_theirs[size_t(b)][k], 1e-7 * (1 + std::abs(j_theirs[size_t(b)][k])))
            << "block " << b << " entry " << k << " knee " << c.knee;
    // Residuals alone, and the focal length's Jacobian when asked for.
    std::vector<double> r_plain(static_cast<size_t>(n));
    ASSERT_TRUE(ours.Evaluate(params, r_plain.data(), nullptr));
    for (int i = 0; i < n; ++i) EXPECT_NEAR(r_plain[size_t(i)], r_ours[size_t(i)], 1e-12 * (1 + std::abs(r_ours[size_t(i)])));
    jo[4] = j_ours[4].data();
    jt[4] = j_theirs[4].data();
    ASSERT_TRUE(ours.Evaluate(params, r_ours.data(), jo));
    ASSERT_TRUE(theirs.Evaluate(params, r_theirs.data(), jt));
    for (size_t k = 0; k < j_ours[4].size(); ++k)
      EXPECT_NEAR(j_ours[4][k], j_theirs[4][k], 1e-7 * (1 + std::abs(j_theirs[4][k])));
    // The robust cases discount pixels: Huber those past its knee alone, Cauchy every one.
    if (c.knee > 0 && !c.trusted) {
      LinkTransferCost plain(&l, cx, cy);
      std::vector<double> r_raw(static_cast<size_t>(n));
      ASSERT_TRUE(plain.Evaluate(params, r_raw.data(), nullptr));
      for (int i = 0; i < n; i += 2) discounted += std::abs(r_ours[size_t(i)]) < std::abs(r_raw[size_t(i)]) - 1e-9;
      EXPECT_GT(discounted, 0);
      if (!c.cauchy) EXPECT_LT(discounted, n / 2);
    }
  }
}

TEST(LinkTransferCost, FailsWhereARayMissesThePlaneOrTheGroundIsBehindB) {
  PlaneLink l;
  l.in_a = {cv::Point2f(200, 150)};
  l.in_b = {cv::Point2f(199.5f, 149.5f)};
  double ea[3] = {0, 0, 0}, ca[3] = {0, 0, -10}, eb[3] = {0, 0, 0}, cb[3] = {0, 0, -10}, f = 400;
  const double* params[5] = {ea, ca, eb, cb, &f};
  LinkTransferCost cost(&l, 199.5, 149.5);
  double r[2];
  EXPECT_TRUE(cost.Evaluate(params, r, nullptr));
  EXPECT_NEAR(r[0], 0.5, 1e-9);  // straight down: the pixel seen where it is, half a pixel from its match
  double up[3] = {0, 3.0, 0};  // a turned so far that the pixel's ray points up, away from the plane
  const double* away[5] = {up, ca, eb, cb, &f};
  EXPECT_FALSE(cost.Evaluate(away, r, nullptr));
  double below[3] = {0, 0, 5};  // b under the plane: the ground behind it
  const double* behind[5] = {ea, ca, eb, below, &f};
  EXPECT_FALSE(cost.Evaluate(behind, r, nullptr));
}

// The adjustment's rotation (for jets) is the one the rest of the engine places frames with.
TEST(PlaneRotation, IsWorldToCamera) {
  for (const PlanePose& pose : {PlanePose{0, 0, 0, {0, 0, -1}}, PlanePose{0.3, 0.02, -0.05, {0, 0, -1}},
                                PlanePose{-2.9, -0.4, 0.7, {0, 0, -1}}, PlanePose{1.6, 1.2, -1.5, {0, 0, -1}}}) {
    const double e[3] = {pose.yaw, pose.pitch, pose.roll};
    double R[9];
    PlaneRotation(e, R);
    const cv::Matx33d want = WorldToCamera(pose);
    for (int k = 0; k < 9; ++k) EXPECT_NEAR(R[k], want(k / 3, k % 3), 1e-15) << "entry " << k;
  }
}

}  // namespace
}  // namespace rolamos

// One link of the plane adjustment (plane_adjustment.h) as Ceres sees it: every matched pixel of
// frame a cast onto the plane z = 0 and seen by frame b, against its match in b (2 residuals a
// pixel), optionally each discounted by a robust loss of its own.
//
// The transfer is a homography, H = K Rb N(cb) M(ca) Ra^T K^-1, so its derivatives are taken
// once a link, with Ceres's jets, and each pixel's follow by the chain rule through the
// projection: with 13 parameters, jets carried through every pixel's arithmetic cost the engine
// a tenth of its patch writing (the adjustment at each patch's close).
#pragma once

#include <ceres/cost_function.h>

#include "geometry/plane_adjustment.h"

namespace rolamos {

// Trusted links weigh as much as kTrustedWeight links each: a group held by one link of the
// chain against several that agree with each other goes where the chain puts it, and those are
// left far off, to be found false.
constexpr double kTrustedWeight = 10.0;
inline double LinkWeight(const PlaneLink& l) { return l.trusted ? kTrustedWeight * l.weight : l.weight; }
inline double PairWeight(const PlaneLink& l, size_t i) { return i < l.pair_weight.size() ? l.pair_weight[i] : 1.0; }

// Parameter blocks: yaw, pitch, roll of a (3), centre of a (3), the same of b (3, 3), the focal
// length (1). With a knee, each pixel is discounted on its own by the robust loss (Huber, or
// Cauchy), the knee scaled by the pixel's weight: its residual r is scaled to sqrt(rho(|r|^2)) /
// |r|, the same sum, so the same minimum, as one robust residual block a pixel. Without (knee 0),
// the pixels are not discounted here. A pixel whose ray misses the plane, or whose ground lies
// behind b, fails the evaluation (as the jets' version did).
class LinkTransferCost final : public ceres::CostFunction {
 public:
  LinkTransferCost(const PlaneLink* link, double cx, double cy, double knee = 0, bool cauchy = false);
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

 private:
  const PlaneLink* l_;
  double cx_, cy_, knee_;
  bool cauchy_;
};

}  // namespace rolamos

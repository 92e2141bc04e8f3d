#include "geometry/link_transfer.h"

#include <cmath>
#include <iterator>

#include <ceres/jet.h>

namespace rolamos {
namespace {

constexpr int kParams = 13;  // ea, ca, eb, cb (3 each), f
constexpr int kBlockSize[5] = {3, 3, 3, 3, 1};
constexpr int kBlockStart[5] = {0, 3, 6, 9, 12};
using Jet = ceres::Jet<double, kParams>;

// The link's homography H = K Rb N(cb) M(ca) Ra^T K^-1 (frame a's pixels -> frame b's, row-major)
// and `ray_z`, the row of Ra^T K^-1 that gives a pixel's ray's vertical component. With
// G = Ra^T K^-1, a pixel p's ray is d = G p; M(ca) takes it to the plane's point where the ray
// from ca meets z = 0 (homogeneous, scaled by d_z), N(cb) to that point less cb, Rb into b's
// camera, K to b's pixels: H p = d_z (f c_x + cx c_z, f c_y + cy c_z, c_z), c = b's camera
// coordinates of the ground point.
template <typename T>
void LinkHomography(const T* ea, const T* ca, const T* eb, const T* cb, const T& f, double cx, double cy, T H[9],
                    T ray_z[3]) {
  T Ra[9], Rb[9];
  PlaneRotation(ea, Ra);
  PlaneRotation(eb, Rb);
  const T inv_f = T(1) / f;
  const T k_inv[9] = {inv_f, T(0), -T(cx) * inv_f, T(0), inv_f, -T(cy) * inv_f, T(0), T(0), T(1)};
  T G[9];  // Ra^T K^-1
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) G[3 * r + c] = Ra[r] * k_inv[c] + Ra[3 + r] * k_inv[3 + c] + Ra[6 + r] * k_inv[6 + c];
  T B[9];  // N(cb) M(ca) G
  for (int c = 0; c < 3; ++c) {
    const T a0 = -ca[2] * G[c] + ca[0] * G[6 + c], a1 = -ca[2] * G[3 + c] + ca[1] * G[6 + c], a2 = G[6 + c];
    B[c] = a0 - cb[0] * a2;
    B[3 + c] = a1 - cb[1] * a2;
    B[6 + c] = -cb[2] * a2;
  }
  T C[9];  // Rb B
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) C[3 * r + c] = Rb[3 * r] * B[c] + Rb[3 * r + 1] * B[3 + c] + Rb[3 * r + 2] * B[6 + c];
  for (int c = 0; c < 3; ++c) {
    H[c] = f * C[c] + T(cx) * C[6 + c];
    H[3 + c] = f * C[3 + c] + T(cy) * C[6 + c];
    H[6 + c] = C[6 + c];
    ray_z[c] = G[6 + c];
  }
}

// The robust loss's factor on a pixel's residual of squared norm s2 (knee a), and its derivative
// in s2; false where the pixel is within the knee (not discounted).
bool RobustScale(double s2, double a, bool cauchy, double* scale, double* d_scale) {
  const double a2 = a * a;
  if (cauchy) {
    if (!(s2 > 1e-12 * a2)) return false;
    const double log_term = std::log(1.0 + s2 / a2);
    const double g = a2 * log_term / s2;  // scale^2
    *scale = std::sqrt(g);
    const double dg = (s2 / (1.0 + s2 / a2) - a2 * log_term) / (s2 * s2);
    *d_scale = dg / (2 * *scale);
    return true;
  }
  if (!(s2 > a2)) return false;
  const double n = std::sqrt(s2), root = std::sqrt(2 * a * n - a2);
  *scale = root / n;
  *d_scale = (a2 - a * n) / (n * n * root) / (2 * n);
  return true;
}

}  // namespace

LinkTransferCost::LinkTransferCost(const PlaneLink* link, double cx, double cy, double knee, bool cauchy)
    : l_(link), cx_(cx), cy_(cy), knee_(knee), cauchy_(cauchy) {
  set_num_residuals(2 * static_cast<int>(link->in_a.size()));
  mutable_parameter_block_sizes()->assign(std::begin(kBlockSize), std::end(kBlockSize));
}

bool LinkTransferCost::Evaluate(double const* const* p, double* residuals, double** jacobians) const {
  double H[9], ray_z[3];
  double dH[9][kParams] = {};
  if (jacobians) {
    Jet ea[3], ca[3], eb[3], cb[3];
    for (int k = 0; k < 3; ++k) {
      ea[k] = Jet(p[0][k], kBlockStart[0] + k);
      ca[k] = Jet(p[1][k], kBlockStart[1] + k);
      eb[k] = Jet(p[2][k], kBlockStart[2] + k);
      cb[k] = Jet(p[3][k], kBlockStart[3] + k);
    }
    Jet Hj[9], zj[3];
    LinkHomography(ea, ca, eb, cb, Jet(p[4][0], kBlockStart[4]), cx_, cy_, Hj, zj);
    for (int k = 0; k < 9; ++k) {
      H[k] = Hj[k].a;
      for (int j = 0; j < kParams; ++j) dH[k][j] = Hj[k].v[j];
    }
    for (int k = 0; k < 3; ++k) ray_z[k] = zj[k].a;
  } else {
    LinkHomography(p[0], p[1], p[2], p[3], p[4][0], cx_, cy_, H, ray_z);
  }
  const double link_weight = LinkWeight(*l_);
  for (size_t i = 0; i < l_->in_a.size(); ++i) {
    const double x = l_->in_a[i].x, y = l_->in_a[i].y;
    // The ray must reach the plane, and the ground it meets lie in front of b.
    const double ray = ray_z[0] * x + ray_z[1] * y + ray_z[2];
    if (!(ray > 1e-6)) return false;
    const double q0 = H[0] * x + H[1] * y + H[2], q1 = H[3] * x + H[4] * y + H[5], q2 = H[6] * x + H[7] * y + H[8];
    if (!(q2 / ray > 1e-6)) return false;
    const double w = link_weight * PairWeight(*l_, i);
    const double u = q0 / q2, v = q1 / q2;
    double* r = residuals + 2 * i;
    r[0] = w * (u - l_->in_b[i].x);
    r[1] = w * (v - l_->in_b[i].y);
    double scale = 1, d_scale = 0;
    const bool robust = knee_ > 0 && RobustScale(r[0] * r[0] + r[1] * r[1], knee_ * PairWeight(*l_, i), cauchy_,
                                                 &scale, &d_scale);
    if (jacobians) {
      // Through the projection: d(q0 / q2) = (dq0 - u dq2) / q2, dq = dH p.
      double J[2][kParams];
      const double s = w / q2;
      for (int j = 0; j < kParams; ++j) {
        const double dq2 = x * dH[6][j] + y * dH[7][j] + dH[8][j];
        J[0][j] = s * (x * dH[0][j] + y * dH[1][j] + dH[2][j] - u * dq2);
        J[1][j] = s * (x * dH[3][j] + y * dH[4][j] + dH[5][j] - v * dq2);
      }
      if (robust) {
        // (scale r)' = scale r' + r scale'(s2) 2 r . r'
        for (int j = 0; j < kParams; ++j) {
          const double ds2 = 2 * (r[0] * J[0][j] + r[1] * J[1][j]);
          J[0][j] = scale * J[0][j] + r[0] * d_scale * ds2;
          J[1][j] = scale * J[1][j] + r[1] * d_scale * ds2;
        }
      }
      for (int b = 0; b < 5; ++b) {
        if (!jacobians[b]) continue;
        for (int k = 0; k < 2; ++k)
          for (int t = 0; t < kBlockSize[b]; ++t)
            jacobians[b][(2 * i + size_t(k)) * size_t(kBlockSize[b]) + size_t(t)] = J[k][kBlockStart[b] + t];
      }
    }
    if (robust) {
      r[0] *= scale;
      r[1] *= scale;
    }
  }
  return true;
}

}  // namespace rolamos

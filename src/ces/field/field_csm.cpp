// Charge-simulation method: assembly and dense solve (see field_csm.h for the method and references).
#include "ces/field/field_csm.h"

#include <eigen3/Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <string>

#include "chrono_like/base/errors.h"

namespace dvi {
namespace ces {

namespace {
constexpr double kTwoPi = 6.283185307179586476925286766559;
}  // namespace

int CsmField::addCylinder(real cx, real cy, real R, real V, int nCharges, real rho) {
  if (!(R > real(0)) || !std::isfinite(R) || !std::isfinite(cx) || !std::isfinite(cy) || !std::isfinite(V))
    throw InputError("CSM cylinder: radius must be positive and all values finite");
  if (!(rho >= real(0) && rho < real(1)))
    throw InputError("CSM cylinder: charge radius fraction must be 0 (automatic) or lie in (0, 1), got " +
                     std::to_string(rho));
  if (nCharges < 0) throw InputError("CSM cylinder: the number of line charges must be >= 0 (0: automatic)");
  for (const CsmConductor& c : conductors_) {
    const real d = std::hypot(cx - c.cx, cy - c.cy);
    if (!(d > R + c.R)) throw InputError("CSM cylinders overlap or touch");
  }
  conductors_.push_back(CsmConductor{cx, cy, R, V});
  m_.push_back(nCharges);
  rho_.push_back(rho);
  solved_ = false;
  return int(conductors_.size()) - 1;
}

real CsmField::solve() {
  if (conductors_.empty()) throw InputError("CSM: no cylinder");
  const int nc = int(conductors_.size());
  // Automatic placement (field_csm.h, "Accuracy"): s_k = max_j R_k^2/(D_kj - R_j), rho = sqrt(s_k/R_k),
  // M = log(1e-12)/log(rho).
  mUsed_.assign(nc, 0);
  rhoUsed_.assign(nc, real(0));
  for (int k = 0; k < nc; ++k) {
    const CsmConductor& c = conductors_[k];
    double s = 0;
    for (int j = 0; j < nc; ++j) {
      if (j == k) continue;
      const double d = std::hypot(double(c.cx) - conductors_[j].cx, double(c.cy) - conductors_[j].cy);
      s = std::max(s, double(c.R) * c.R / (d - conductors_[j].R));
    }
    double rho = rho_[k] > real(0) ? double(rho_[k]) : std::min(0.95, std::max(0.05, std::sqrt(s / c.R)));
    int m = m_[k];
    if (m == 0) {
      const double ratio = std::max(rho, s / (rho * c.R));
      m = ratio < 1 ? int(std::ceil(std::log(1e-12) / std::log(ratio))) : 400;
      m = std::min(400, std::max(8, m));
    }
    mUsed_[k] = m;
    rhoUsed_[k] = real(rho);
  }
  charges_.clear();
  first_.assign(nc, 0);
  std::vector<real> px, py, pv;  // contour points and their potentials
  for (int k = 0; k < nc; ++k) {
    const CsmConductor& c = conductors_[k];
    first_[k] = int(charges_.size());
    for (int j = 0; j < mUsed_[k]; ++j) {
      const double t = kTwoPi * j / mUsed_[k];
      charges_.push_back(CsmLineCharge{real(c.cx + rhoUsed_[k] * c.R * std::cos(t)),
                                       real(c.cy + rhoUsed_[k] * c.R * std::sin(t)), real(0)});
      px.push_back(real(c.cx + c.R * std::cos(t)));
      py.push_back(real(c.cy + c.R * std::sin(t)));
      pv.push_back(c.V);
    }
  }
  const int n = int(charges_.size());
  // Unknowns: mu_j = lambda_j / (2 pi eps0) (volts, keeps the matrix O(1)) and phi_inf.
  // Row i < n: phi_inf - sum_j mu_j ln|P_i - S_j| = V_i. Row n: sum_j mu_j = 0.
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(n + 1, n + 1);
  Eigen::VectorXd b = Eigen::VectorXd::Zero(n + 1);
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) {
      const double dx = double(px[i]) - double(charges_[j].x), dy = double(py[i]) - double(charges_[j].y);
      A(i, j) = -0.5 * std::log(dx * dx + dy * dy);
    }
    A(i, n) = 1.0;
    b(i) = double(pv[i]);
  }
  for (int j = 0; j < n; ++j) A(n, j) = 1.0;
  const Eigen::VectorXd x = A.colPivHouseholderQr().solve(b);
  if (!x.allFinite()) throw InputError("CSM: the collocation system could not be solved");
  for (int j = 0; j < n; ++j) charges_[j].lambda = real(x(j) / double(kInv2PiEps0));
  phiInf_ = real(x(n));
  solved_ = true;

  real residual = 0;
  for (int i = 0; i < n; ++i) {
    real phi, ex, ey;
    csmRaw(charges_.data(), n, phiInf_, px[i], py[i], phi, ex, ey);
    residual = std::max(residual, real(std::fabs(phi - pv[i])));
  }
  return residual;
}

real CsmField::cylinderCharge(int k) const {
  if (!solved_ || k < 0 || k >= int(conductors_.size())) throw InputError("CSM: no such solved cylinder");
  double s = 0;
  for (int j = first_[k]; j < first_[k] + mUsed_[k]; ++j) s += double(charges_[j].lambda);
  return real(s);
}

CsmFieldView CsmField::view() const {
  return CsmFieldView{charges_.data(), int(charges_.size()), conductors_.data(), int(conductors_.size()), phiInf_};
}

real CsmField::maxSurfaceError(int nSamples) const {
  if (!solved_) throw InputError("CSM: not solved");
  real err = 0;
  for (const CsmConductor& c : conductors_) {
    for (int i = 0; i < nSamples; ++i) {
      const double t = kTwoPi * (i + 0.5) / nSamples;
      real phi, ex, ey;
      csmRaw(charges_.data(), int(charges_.size()), phiInf_, real(c.cx + c.R * std::cos(t)),
             real(c.cy + c.R * std::sin(t)), phi, ex, ey);
      err = std::max(err, real(std::fabs(phi - c.V)));
    }
  }
  return err;
}

}  // namespace ces
}  // namespace dvi

// A C++ Ceres reference for the P2 bundle adjustment (bench/bench_reference.py): the same
// least-squares problem as the Python service, written the way a Ceres user would write it,
// with one automatically differentiated block per image observation. Not part of the product.
//
// P2 (docs/models.md): in the local geodetic frame (east, north, up; m) the perspective centre
// S(tau) = c0 + c1 tau + c2 tau^2 (+ c3 tau^3) per axis and the angles omega, phi, kappa are
// polynomials of tau = line * tau_per_line; M = Rx(omega) Ry(phi) Rz(kappa) turns object
// differences into the camera frame, d = M (P - S). The line of a ground point is where the
// along-track image coordinate -f d_x / d_z equals the principal point x0 (Newton's method from
// the observed line, differentiated through by the Jets); the column is cc + (-f d_y/d_z - y0)/px.
// Residuals: (observed - projected) / sigma, in pixels. Header states and weighted control
// points are linear priors. Input: bench/ceres_reference/export_block.py.
//
// Usage: p2_autodiff INPUT [--threads N] [--covariance 0|1] [--statistical-stop 0|1]
//                         [--max-iterations N] [--form exact|time] [--settings service|ceres]
//                         [--nonmonotonic 0|1] [--out RESULT]
// --settings ceres: Ceres' default solver options (trust region, tolerances) and no statistical stop.
// --nonmonotonic 0: with the service's settings, monotonic steps even on large blocks.
// RESULT: per image, its 14 adjusted parameters then their a posteriori standard deviations.
// Prints one JSON line with the timings (s), iterations, costs and sigma0.

#include <Eigen/Dense>
#include <Eigen/Sparse>
#include <ceres/ceres.h>

#include <array>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <limits>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

namespace {

constexpr int kCoef = 24;
constexpr int kFree = 14;  // P2: X, Y, Z quadratic (9), omega, phi constant (2), kappa quadratic (3)

double value_of(double x) { return x; }
template <typename J>
double value_of(const J& x) { return x.a; }

struct Image {
  double base[kCoef];
  int free_idx[kFree];
  double params[kFree];
  double sigma[kFree] = {};  // a posteriori standard deviations of params (with --covariance 1)
  int m = 0;
  std::vector<double> a, b, w;  // prior rows: w (A q - b)
};

struct Point {
  int estimated = 0, role = 0;
  double xyz[3], known[3], sigma[3];
};

struct Observation {
  int image, point;
  double oc[9];  // line, column, sigma, f (mm), pixel (mm), x0, y0 (mm), column centre, tau/line
};

// Camera-frame direction d = M (P - S) and its tau-derivative at tau, for coefficients c.
template <typename T>
void camera_state(const T* c, const T& tau, const T* p, T* d, T* ddt) {
  T s[3], sdot[3], ang[3], angdot[3];
  for (int e = 0; e < 3; ++e) {
    const T* k = c + 4 * e;
    s[e] = k[0] + tau * (k[1] + tau * (k[2] + tau * k[3]));
    sdot[e] = k[1] + tau * (2.0 * k[2] + 3.0 * tau * k[3]);
    const T* a = c + 4 * (3 + e);
    ang[e] = a[0] + tau * (a[1] + tau * (a[2] + tau * a[3]));
    angdot[e] = a[1] + tau * (2.0 * a[2] + 3.0 * tau * a[3]);
  }
  using std::cos;
  using std::sin;
  const T co = cos(ang[0]), so = sin(ang[0]), cp = cos(ang[1]), sp = sin(ang[1]), ck = cos(ang[2]), sk = sin(ang[2]);
  // M = Rx(omega) Ry(phi) Rz(kappa) and its partial derivatives
  const T m[9] = {cp * ck, -cp * sk, sp,
                  co * sk + so * sp * ck, co * ck - so * sp * sk, -so * cp,
                  so * sk - co * sp * ck, so * ck + co * sp * sk, co * cp};
  const T dmo[9] = {T(0.0), T(0.0), T(0.0),
                    -so * sk + co * sp * ck, -so * ck - co * sp * sk, -co * cp,
                    co * sk + so * sp * ck, co * ck - so * sp * sk, -so * cp};
  const T dmp[9] = {-sp * ck, sp * sk, cp,
                    so * cp * ck, -so * cp * sk, so * sp,
                    -co * cp * ck, co * cp * sk, -co * sp};
  const T dmk[9] = {-cp * sk, -cp * ck, T(0.0),
                    co * ck - so * sp * sk, -co * sk - so * sp * ck, T(0.0),
                    so * ck + co * sp * sk, -so * sk + co * sp * ck, T(0.0)};
  const T v[3] = {p[0] - s[0], p[1] - s[1], p[2] - s[2]};
  for (int i = 0; i < 3; ++i) {
    d[i] = T(0.0);
    ddt[i] = T(0.0);
    for (int j = 0; j < 3; ++j) {
      const T mij = m[3 * i + j];
      const T dmij = dmo[3 * i + j] * angdot[0] + dmp[3 * i + j] * angdot[1] + dmk[3 * i + j] * angdot[2];
      d[i] += mij * v[j];
      ddt[i] += dmij * v[j] - mij * sdot[j];
    }
  }
}

// The image's 24 coefficients: its held values with the 14 free ones (q) put in their places.
template <typename T>
void coefficients(const Image& img, const T* q, T* c) {
  for (int k = 0; k < kCoef; ++k) c[k] = T(img.base[k]);
  for (int j = 0; j < kFree; ++j) c[img.free_idx[j]] = q[j];
}

// One image observation: residuals (observed - projected) / sigma in pixels. kExact: the line
// found by Newton's method (the service's projection). Otherwise the collinearity at the
// observed line's time (no line search): the along-track image coordinate must be the principal
// point's, the column the observed one; not the same objective (its along-track residual is a
// focal-plane distance at a fixed time), but the cheaper form many pushbroom adjustments use
// (--form time).
template <bool kExact>
struct ObservationResidual {
  ObservationResidual(const Image& img, const Observation& o) : img_(img), o_(o) {}

  template <typename T>
  bool operator()(const T* q, const T* p, T* r) const {
    T c[kCoef];
    coefficients(img_, q, c);
    const double f = o_.oc[3], px = o_.oc[4], x0 = o_.oc[5], y0 = o_.oc[6], cc = o_.oc[7], tpl = o_.oc[8];
    const double w = 1.0 / o_.oc[2];
    T line(o_.oc[0]);
    T d[3], ddt[3];
    camera_state(c, line * tpl, p, d, ddt);
    if (!kExact) {
      r[0] = (-f * d[0] / d[2] - x0) / px * w;
      r[1] = (o_.oc[1] - (cc + (-f * d[1] / d[2] - y0) / px)) * w;
      return true;
    }
    for (int it = 0; it < 30; ++it) {
      const T g = -f * d[0] / d[2] - x0;
      const T dg = -f * (ddt[0] * d[2] - d[0] * ddt[2]) / (d[2] * d[2]) * tpl;
      const T step = g / dg;
      line -= step;
      camera_state(c, line * tpl, p, d, ddt);
      if (!std::isfinite(value_of(step))) return false;
      if (std::abs(value_of(step)) < 1e-8) break;
    }
    const T col = cc + (-f * d[1] / d[2] - y0) / px;
    r[0] = (o_.oc[0] - line) * w;
    r[1] = (o_.oc[1] - col) * w;
    return true;
  }

  const Image& img_;
  const Observation& o_;
};

// r = w (A q - b): a linear prior on one parameter block (states, control coordinates)
class LinearPrior : public ceres::CostFunction {
 public:
  LinearPrior(int m, int n, const double* a, const double* b, const double* w) : m_(m), n_(n), a_(a, a + m * n), b_(b, b + m), w_(w, w + m) {
    set_num_residuals(m);
    mutable_parameter_block_sizes()->push_back(n);
  }
  bool Evaluate(double const* const* x, double* r, double** jac) const override {
    for (int i = 0; i < m_; ++i) {
      double s = -b_[i];
      for (int j = 0; j < n_; ++j) s += a_[i * n_ + j] * x[0][j];
      r[i] = w_[i] * s;
      if (jac && jac[0])
        for (int j = 0; j < n_; ++j) jac[0][i * n_ + j] = w_[i] * a_[i * n_ + j];
    }
    return true;
  }

 private:
  int m_, n_;
  std::vector<double> a_, b_, w_;
};

// The service's statistical stop: two successive successful iterations lowering chi-square
// (2 cost) by less than 1e-3 end the solve.
class StatisticalStop : public ceres::IterationCallback {
 public:
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& s) override {
    if (s.iteration > 0 && s.step_is_successful) {
      // a non-monotonic step above the best cost so far is no convergence (as the service's)
      small_ = (s.cost <= best_ && 2.0 * (last_ - s.cost) < 1e-3) ? small_ + 1 : 0;
      if (small_ >= 2) return ceres::SOLVER_TERMINATE_SUCCESSFULLY;
    }
    if (s.step_is_successful || s.iteration == 0) {
      last_ = s.cost;
      best_ = std::min(best_, s.cost);
    }
    return ceres::SOLVER_CONTINUE;
  }

 private:
  double last_ = 0.0;
  double best_ = std::numeric_limits<double>::infinity();
  int small_ = 0;
};

void expect(std::istream& in, const std::string& word) {
  std::string w;
  in >> w;
  if (w != word) throw std::runtime_error("expected '" + word + "', read '" + w + "'");
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// The covariance of the images' parameters (all pairs) and each estimated point's 3 x 3 block,
// unscaled (multiply by sigma0^2), from the normal matrix reduced to the images (the Schur
// complement), as a photogrammetric bundle adjustment computes it. Ceres' own Covariance with
// SPARSE_QR declares these ill-conditioned Jacobians rank deficient (pitch against along-track
// position, condition ~1e11 per image).
struct SchurCovariance {
  Eigen::MatrixXd images;               // (14 n_images)^2
  std::vector<Eigen::Matrix3d> points;  // per estimated point
};

SchurCovariance schur_covariance(ceres::Problem& problem, std::vector<Image>& images, std::vector<Point>& points, int threads) {
  ceres::Problem::EvaluateOptions eo;
  eo.num_threads = threads;
  for (auto& im : images) eo.parameter_blocks.push_back(im.params);
  std::vector<Point*> est;
  for (auto& p : points)
    if (p.estimated && problem.HasParameterBlock(p.xyz)) {
      eo.parameter_blocks.push_back(p.xyz);
      est.push_back(&p);
    }
  ceres::CRSMatrix crs;
  problem.Evaluate(eo, nullptr, nullptr, nullptr, &crs);
  const int nc = kFree * static_cast<int>(images.size());
  Eigen::Map<const Eigen::SparseMatrix<double, Eigen::RowMajor>> j(crs.num_rows, crs.num_cols, static_cast<int>(crs.values.size()),
                                                                   crs.rows.data(), crs.cols.data(), crs.values.data());
  const Eigen::SparseMatrix<double> n = j.transpose() * j;  // column-major normal matrix
  Eigen::MatrixXd s = Eigen::MatrixXd(n.topLeftCorner(nc, nc));
  std::vector<Eigen::Matrix3d> npp_inv(est.size());
  std::vector<std::vector<int>> rows(est.size());
  std::vector<Eigen::MatrixXd> w(est.size());  // N_cp of each point (its images' rows x 3)
  for (size_t q = 0; q < est.size(); ++q) {
    const int c0 = nc + 3 * static_cast<int>(q);
    Eigen::Matrix3d npp = Eigen::Matrix3d::Zero();
    std::vector<std::array<double, 3>> vals;
    for (int k = 0; k < 3; ++k)
      for (Eigen::SparseMatrix<double>::InnerIterator it(n, c0 + k); it; ++it) {
        if (it.row() >= c0 && it.row() < c0 + 3) npp(it.row() - c0, k) = it.value();
        else if (it.row() < nc) {
          if (k == 0) { rows[q].push_back(it.row()); vals.push_back({it.value(), 0.0, 0.0}); }
          else {
            const auto at = std::lower_bound(rows[q].begin(), rows[q].end(), it.row()) - rows[q].begin();
            vals[at][k] = it.value();
          }
        }
      }
    w[q].resize(rows[q].size(), 3);
    for (size_t r = 0; r < rows[q].size(); ++r) w[q].row(r) << vals[r][0], vals[r][1], vals[r][2];
    npp_inv[q] = npp.inverse();
    const Eigen::MatrixXd update = w[q] * npp_inv[q] * w[q].transpose();
    for (size_t a = 0; a < rows[q].size(); ++a)
      for (size_t b = 0; b < rows[q].size(); ++b) s(rows[q][a], rows[q][b]) -= update(a, b);
  }
  SchurCovariance out;
  out.images = s.ldlt().solve(Eigen::MatrixXd::Identity(nc, nc));
  out.points.resize(est.size());
  for (size_t q = 0; q < est.size(); ++q) {
    Eigen::MatrixXd sub(rows[q].size(), rows[q].size());
    for (size_t a = 0; a < rows[q].size(); ++a)
      for (size_t b = 0; b < rows[q].size(); ++b) sub(a, b) = out.images(rows[q][a], rows[q][b]);
    const Eigen::MatrixXd g = w[q] * npp_inv[q];
    out.points[q] = npp_inv[q] + g.transpose() * sub * g;
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::cerr << "usage: p2_autodiff INPUT [--threads N] [--covariance 0|1] [--statistical-stop 0|1] [--max-iterations N] [--form exact|time] [--settings service|ceres] [--nonmonotonic 0|1] [--out FILE]\n";
    return 2;
  }
  int threads = 2, covariance = 1, statistical = 1, max_iterations = 50, nonmonotonic = 1;
  std::string form = "exact", settings = "service";
  std::string out_path;
  for (int i = 2; i + 1 < argc; i += 2) {
    const std::string k = argv[i], v = argv[i + 1];
    if (k == "--threads") threads = std::stoi(v);
    else if (k == "--covariance") covariance = std::stoi(v);
    else if (k == "--statistical-stop") statistical = std::stoi(v);
    else if (k == "--max-iterations") max_iterations = std::stoi(v);
    else if (k == "--out") out_path = v;
    else if (k == "--form") form = v;
    else if (k == "--settings") settings = v;
    else if (k == "--nonmonotonic") nonmonotonic = std::stoi(v);
    else { std::cerr << "unknown option " << k << "\n"; return 2; }
  }
  const auto t_start = std::chrono::steady_clock::now();
  std::ifstream in(argv[1]);
  std::vector<Image> images;
  std::vector<Point> points;
  std::vector<Observation> obs;
  try {
    expect(in, "PBA-P2");
    int version;
    in >> version;
    size_t n;
    expect(in, "images");
    in >> n;
    images.resize(n);
    for (auto& im : images) {
      int nfree;
      in >> nfree;
      if (nfree != kFree) throw std::runtime_error("an image without the 14 free P2 parameters");
      for (double& c : im.base) in >> c;
      for (int& k : im.free_idx) in >> k;
      for (double& q : im.params) in >> q;
      in >> im.m;
      im.a.resize(im.m * kFree);
      im.b.resize(im.m);
      im.w.resize(im.m);
      for (double& x : im.a) in >> x;
      for (double& x : im.b) in >> x;
      for (double& x : im.w) in >> x;
    }
    expect(in, "points");
    in >> n;
    points.resize(n);
    auto read_or_nan = [&in](double& x) {
      std::string s;
      in >> s;
      x = (s == "nan") ? std::numeric_limits<double>::quiet_NaN() : std::stod(s);
    };
    for (auto& p : points) {
      in >> p.estimated >> p.role;
      for (double& x : p.xyz) read_or_nan(x);
      for (double& x : p.known) read_or_nan(x);
      for (double& x : p.sigma) read_or_nan(x);
    }
    expect(in, "observations");
    in >> n;
    obs.resize(n);
    for (auto& o : obs) {
      in >> o.image >> o.point;
      for (double& x : o.oc) in >> x;
    }
    if (!in) throw std::runtime_error("truncated input");
  } catch (const std::exception& e) {
    std::cerr << "p2_autodiff: " << argv[1] << ": " << e.what() << "\n";
    return 2;
  }
  const double read_s = seconds_since(t_start);

  auto t0 = std::chrono::steady_clock::now();
  ceres::Problem problem;
  for (const auto& o : obs) {
    ceres::CostFunction* cost;
    if (form == "time") cost = new ceres::AutoDiffCostFunction<ObservationResidual<false>, 2, kFree, 3>(new ObservationResidual<false>(images[o.image], o));
    else cost = new ceres::AutoDiffCostFunction<ObservationResidual<true>, 2, kFree, 3>(new ObservationResidual<true>(images[o.image], o));
    problem.AddResidualBlock(cost, nullptr, images[o.image].params, points[o.point].xyz);
  }
  for (auto& im : images)
    if (im.m > 0) problem.AddResidualBlock(new LinearPrior(im.m, kFree, im.a.data(), im.b.data(), im.w.data()), nullptr, im.params);
  const double eye[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  for (auto& p : points) {
    if (!problem.HasParameterBlock(p.xyz)) continue;
    if (!p.estimated) {
      problem.SetParameterBlockConstant(p.xyz);
    } else if (p.role == 1 && std::isfinite(p.sigma[0])) {
      const double w[3] = {1.0 / p.sigma[0], 1.0 / p.sigma[1], 1.0 / p.sigma[2]};
      problem.AddResidualBlock(new LinearPrior(3, 3, eye, p.known, w), nullptr, p.xyz);
    }
  }
  const double build_s = seconds_since(t0);

  ceres::Solver::Options so;
  so.linear_solver_type = ceres::SPARSE_SCHUR;
  so.num_threads = threads;
  so.max_num_iterations = max_iterations;
  if (settings == "service") {  // the service's (solver/engine/backend.py), with its statistical stop
    so.function_tolerance = 1e-10;
    so.parameter_tolerance = 1e-10;
    so.gradient_tolerance = 1e-14;
    so.initial_trust_region_radius = 1e12;
    // non-monotonic steps on large blocks, as the service (solver/engine/backend.py: 2,000 or
    // more residual blocks there, one per ground point; here one per observation)
    so.use_nonmonotonic_steps = nonmonotonic && problem.NumResidualBlocks() >= 2000;
  } else {
    statistical = 0;  // Ceres' defaults: trust region 1e4, tolerances 1e-6 / 1e-8 / 1e-10
  }
  so.logging_type = ceres::SILENT;
  StatisticalStop stop;
  if (statistical) so.callbacks.push_back(&stop);
  ceres::Solver::Summary summary;
  t0 = std::chrono::steady_clock::now();
  ceres::Solve(so, &problem, &summary);
  const double solve_s = seconds_since(t0);
  const int iterations = summary.num_successful_steps + summary.num_unsuccessful_steps;
  const int n_res = problem.NumResiduals();
  const int n_par = problem.NumParameters() - 3 * static_cast<int>(std::count_if(points.begin(), points.end(), [&](const Point& p) {
    return problem.HasParameterBlock(p.xyz) && !p.estimated; }));
  const double sigma0 = std::sqrt(2.0 * summary.final_cost / std::max(1, n_res - n_par));

  double covariance_s = 0.0;
  double mean_sigma_x0 = 0.0, mean_sigma_point = 0.0;
  if (covariance) {
    t0 = std::chrono::steady_clock::now();
    const SchurCovariance cov = schur_covariance(problem, images, points, threads);
    const double s2 = sigma0 * sigma0;
    for (size_t i = 0; i < images.size(); ++i) {
      for (int j = 0; j < kFree; ++j) images[i].sigma[j] = std::sqrt(cov.images(i * kFree + j, i * kFree + j) * s2);
      mean_sigma_x0 += images[i].sigma[0] / images.size();
    }
    for (const auto& c : cov.points) mean_sigma_point += std::sqrt(c.trace() * s2) / cov.points.size();
    covariance_s = seconds_since(t0);
  }
  if (!out_path.empty()) {
    std::ofstream out(out_path);
    out.precision(17);
    for (const auto& im : images) {
      for (double q : im.params) out << q << " ";
      for (double q : im.sigma) out << q << " ";
      out << "\n";
    }
  }
  std::printf(
      "{\"form\": \"%s\", \"settings\": \"%s\", \"observations\": %zu, \"images\": %zu, \"threads\": %d, \"read_s\": %.4f, \"build_s\": %.4f, \"solve_s\": %.4f, "
      "\"covariance_s\": %.4f, \"process_s\": %.4f, \"iterations\": %d, \"per_iteration_s\": %.4f, "
      "\"residual_evaluation_s\": %.4f, \"jacobian_evaluation_s\": %.4f, \"linear_solver_s\": %.4f, "
      "\"initial_cost\": %.10g, \"final_cost\": %.10g, \"sigma0\": %.6f, \"mean_sigma_x0_m\": %.6g, "
      "\"mean_sigma_point_m\": %.6g, \"termination\": \"%s\"}\n",
      form.c_str(), settings.c_str(), obs.size(), images.size(), threads, read_s, build_s, solve_s, covariance_s, seconds_since(t_start), iterations,
      solve_s / std::max(1, iterations), summary.residual_evaluation_time_in_seconds, summary.jacobian_evaluation_time_in_seconds,
      summary.linear_solver_time_in_seconds, summary.initial_cost, summary.final_cost, sigma0, mean_sigma_x0,
      mean_sigma_point, ceres::TerminationTypeToString(summary.termination_type));
  return 0;
}

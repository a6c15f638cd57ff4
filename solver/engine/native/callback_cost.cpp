// Compiled Ceres cost functions for pyceres: residual blocks whose Evaluate calls a C function
// pointer (a numba @cfunc of solver/kernels/callbacks.py) or applies a constant linear form,
// without the Python trampoline and without the GIL, so Ceres may evaluate on every core.
//
// Built by scripts/build_native.py against the pybind11 version of the pyceres wheel (its
// internals must match, so pyceres' CostFunction type is our base) and the header
// ceres/cost_function.h (Debian's libceres-dev). Nothing is linked against libceres: the two
// out-of-line members of ceres::CostFunction are defined here (the wheel links Ceres statically).
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <ceres/cost_function.h>

#include <atomic>
#include <cstdint>
#include <cstring>
#include <memory>
#include <mutex>
#include <thread>
#include <unordered_map>
#include <vector>

namespace py = pybind11;

namespace ceres {
CostFunction::CostFunction() : num_residuals_(0) {}
CostFunction::~CostFunction() {}
}  // namespace ceres

namespace {

// bool fn(block, table, parameters, residuals, jacobians, want_jacobians)
// block: the residual block's descriptor (int64 words, see solver/kernels/callbacks.py);
// table: this thread's copy of the shared image table (the kernels may cache in it);
// jacobians: null when want_jacobians is 0, else every entry non-null.
using BlockFn = bool (*)(const void*, double*, const double* const*, double*, double**, int);

std::atomic<std::uint64_t> next_generation{1};

// What every cost function of one solve shares: the image table (copied once per thread that
// evaluates, because pass-propagated images cache their trajectory segment in it) and the
// cancel flag.
class Evaluator {
 public:
  Evaluator(py::array_t<double, py::array::c_style> table)
      : table_(table), generation_(next_generation.fetch_add(1)) {}

  void cancel() { cancelled_.store(true, std::memory_order_relaxed); }
  bool cancelled() const { return cancelled_.load(std::memory_order_relaxed); }
  int threads_used() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return static_cast<int>(copies_.size());
  }

  double* thread_table() const {
    thread_local std::uint64_t cached_generation = 0;
    thread_local double* cached = nullptr;
    if (cached_generation == generation_) return cached;
    std::lock_guard<std::mutex> lock(mutex_);
    auto& copy = copies_[std::this_thread::get_id()];
    if (copy.empty()) {
      copy.assign(table_.data(), table_.data() + table_.size());
    }
    cached = copy.data();
    cached_generation = generation_;
    return cached;
  }

 private:
  py::array_t<double, py::array::c_style> table_;  // keeps the master table alive
  const std::uint64_t generation_;
  std::atomic<bool> cancelled_{false};
  mutable std::mutex mutex_;
  mutable std::unordered_map<std::thread::id, std::vector<double>> copies_;
};

class CallbackCost : public ceres::CostFunction {
 public:
  // ``block``: the address of the block's descriptor; ``owner``: a Python object holding every
  // array the descriptor points into (directly or through the context), referenced for as long as
  // the cost function lives, so no address can outlive its memory.
  CallbackCost(std::shared_ptr<Evaluator> evaluator, std::uintptr_t fn, std::uintptr_t block,
               int num_residuals, const std::vector<int>& block_sizes, py::object owner)
      : evaluator_(std::move(evaluator)),
        fn_(reinterpret_cast<BlockFn>(fn)),
        block_(reinterpret_cast<const void*>(block)),
        owner_(std::move(owner)),
        jacobian_size_(0) {
    set_num_residuals(num_residuals);
    for (int s : block_sizes) {
      mutable_parameter_block_sizes()->push_back(s);
      jacobian_size_ += static_cast<std::size_t>(s) * num_residuals;
    }
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    if (evaluator_->cancelled()) return false;
    double* table = evaluator_->thread_table();
    if (jacobians == nullptr) {
      return fn_(block_, table, parameters, residuals, nullptr, 0);
    }
    const auto& sizes = parameter_block_sizes();
    bool complete = true;
    for (std::size_t i = 0; i < sizes.size(); ++i) complete = complete && jacobians[i] != nullptr;
    if (complete) return fn_(block_, table, parameters, residuals, jacobians, 1);
    // Ceres leaves out the Jacobians of constant blocks: the kernel writes those into scratch.
    thread_local std::vector<double> scratch;
    thread_local std::vector<double*> filled;
    scratch.resize(jacobian_size_);
    filled.resize(sizes.size());
    std::size_t offset = 0;
    for (std::size_t i = 0; i < sizes.size(); ++i) {
      filled[i] = jacobians[i] != nullptr ? jacobians[i] : scratch.data() + offset;
      offset += static_cast<std::size_t>(sizes[i]) * num_residuals();
    }
    return fn_(block_, table, parameters, residuals, filled.data(), 1);
  }

 private:
  std::shared_ptr<Evaluator> evaluator_;
  BlockFn fn_;
  const void* block_;
  py::object owner_;
  std::size_t jacobian_size_;
};

// residuals = A x - b on one parameter block (A: m x n, row-major; already whitened).
class LinearCost : public ceres::CostFunction {
 public:
  LinearCost(std::shared_ptr<Evaluator> evaluator,
             py::array_t<double, py::array::c_style | py::array::forcecast> a,
             py::array_t<double, py::array::c_style | py::array::forcecast> b)
      : evaluator_(std::move(evaluator)) {
    if (a.ndim() != 2 || b.ndim() != 1 || a.shape(0) != b.shape(0)) {
      throw std::invalid_argument("LinearCost: A must be (m, n) and b (m,)");
    }
    rows_ = static_cast<int>(a.shape(0));
    cols_ = static_cast<int>(a.shape(1));
    a_.assign(a.data(), a.data() + a.size());
    b_.assign(b.data(), b.data() + b.size());
    set_num_residuals(rows_);
    mutable_parameter_block_sizes()->push_back(cols_);
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    if (evaluator_ && evaluator_->cancelled()) return false;
    const double* x = parameters[0];
    for (int r = 0; r < rows_; ++r) {
      double s = -b_[r];
      const double* row = a_.data() + static_cast<std::size_t>(r) * cols_;
      for (int c = 0; c < cols_; ++c) s += row[c] * x[c];
      residuals[r] = s;
    }
    if (jacobians != nullptr && jacobians[0] != nullptr) {
      std::memcpy(jacobians[0], a_.data(), sizeof(double) * a_.size());
    }
    return true;
  }

 private:
  std::shared_ptr<Evaluator> evaluator_;
  int rows_ = 0, cols_ = 0;
  std::vector<double> a_, b_;
};

}  // namespace

PYBIND11_MODULE(callback_cost, m) {
  m.doc() = "Compiled Ceres cost functions calling numba C callbacks (see callback_cost.cpp)";
  py::module_::import("pyceres");  // registers ceres::CostFunction, our base type
  py::class_<Evaluator, std::shared_ptr<Evaluator>>(m, "Evaluator")
      .def(py::init<py::array_t<double, py::array::c_style>>(), py::arg("table"))
      .def("cancel", &Evaluator::cancel)
      .def_property_readonly("cancelled", &Evaluator::cancelled)
      .def_property_readonly("threads_used", &Evaluator::threads_used);
  py::class_<CallbackCost, ceres::CostFunction, py::smart_holder>(m, "CallbackCost")
      .def(py::init<std::shared_ptr<Evaluator>, std::uintptr_t, std::uintptr_t, int, const std::vector<int>&, py::object>(),
           py::arg("evaluator"), py::arg("function_address"), py::arg("block_address"),
           py::arg("num_residuals"), py::arg("block_sizes"), py::arg("owner"));
  py::class_<LinearCost, ceres::CostFunction, py::smart_holder>(m, "LinearCost")
      .def(py::init<std::shared_ptr<Evaluator>, py::array_t<double, py::array::c_style | py::array::forcecast>,
                    py::array_t<double, py::array::c_style | py::array::forcecast>>(),
           py::arg("evaluator"), py::arg("a"), py::arg("b"));
  m.attr("ABI") = 3;
}

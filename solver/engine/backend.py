"""Ceres backend: the only module that uses pyceres (imported by :mod:`solver.engine.ceres_import`).

Residual-block design (measured in ../shared/PYCERES_NOTES.md): every Python cost function
costs a trampoline call, so

* observations of *fixed* ground points of one image form one vectorised block per image
  (resection block: one call for all of them);
* each *estimated* point (tie point, weighted control point) has one block holding all its
  observations (at most three per block in large least-squares blocks: :func:`split_rays`),
  with the point and the images that see it as parameter blocks (Schur elimination keeps
  working: one e-block per residual block);
* survey priors of weighted control points are Ceres' built-in ``NormalPrior`` (no trampoline).

The arithmetic is in :mod:`solver.kernels` (numba). Cancellation: the cost functions return
False once the cancel hook said so (Ceres then stops within the iteration), and an iteration
callback stops the solve cleanly between iterations; progress is reported from that callback.
"""

from __future__ import annotations

import math
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator

import numpy as np

from solver.blocks import registry as block_kinds
from solver.engine import native
from solver.engine.ceres_import import import_pyceres
from solver.engine.heap import release_freed_memory
from solver.engine.packed_tables import camera_table, image_table
from solver.engine.residual_blocks import ResidualBlocks, fixed_blocks, fixed_points, point_blocks
from solver.engine.terms import block_owner, family_terms
from solver.kernels import fixed_obs_block, point_obs_block
from solver.schema.settings import SolveSettings
from solver.state import AdjustmentState

pyceres = import_pyceres()  # glog's failure signal handlers left out (solver/engine/ceres_import.py)


class SolveControl:
    """Progress and cancellation shared by the cost functions and the iteration callback."""

    def __init__(
        self,
        progress: Callable[..., None] | None,
        cancel: Callable[[], bool] | None,
        max_iterations: int,
        fraction_range: tuple[float, float] = (0.1, 0.9),
        poll_interval_s: float = 0.1,
    ):
        self.progress = progress
        self.cancel = cancel
        self.max_iterations = max_iterations
        self.lo, self.hi = fraction_range
        self.poll_interval_s = poll_interval_s
        self.cancelled = False
        self._next_poll = 0.0
        self.history: list[dict[str, float]] = []
        self._last_fraction = self.lo
        self.statistically_converged = False
        self._small_steps = 0
        self._best = math.inf  # the lowest cost of this objective so far

    def restart(self) -> None:
        """A new objective (terms refreshed between solves): the statistical test starts again."""
        self.statistically_converged = False
        self._small_steps = 0
        self._best = math.inf  # its first cost is compared with the last of the objective before (as before restarts existed)

    def poll(self) -> bool:
        """True once cancellation was requested (cheap; the hook is called at most every 0.1 s)."""
        if self.cancelled or self.cancel is None:
            return self.cancelled
        now = time.monotonic()
        if now >= self._next_poll:
            self._next_poll = now + self.poll_interval_s
            if self.cancel():
                self.cancelled = True
        return self.cancelled

    # Two successive successful iterations that lower chi-square (= 2 cost) by less than this
    # end the solve: every parameter then moves by less than ~0.03 of its standard deviation.
    # Ill-conditioned blocks otherwise creep on for tens of iterations at a negligible gain.
    CHI2_TOLERANCE = 1e-3

    def iteration(self, it: int, cost: float, step_successful: bool = True) -> None:
        if self.history and step_successful:
            # with non-monotonic steps (large blocks) a successful step may raise the cost above
            # the best so far (Ceres keeps the best parameters): that is no convergence
            if cost > self._best:
                self._small_steps = 0
            elif 2.0 * (self.history[-1]["cost"] - cost) < self.CHI2_TOLERANCE:
                self._small_steps += 1
            else:
                self._small_steps = 0
            if self._small_steps >= 2:
                self.statistically_converged = True
        if step_successful or not self.history:
            self.history.append({"iteration": it, "cost": cost})
            self._best = min(self._best, cost)
        if self.progress is not None:
            # progress grows with iterations and never decreases
            frac = self.lo + (self.hi - self.lo) * (1.0 - math.exp(-(it + 1) / 6.0))
            self._last_fraction = max(self._last_fraction, frac)
            self.progress(self._last_fraction, f"iteration {it}, cost {cost:.6g}", {"iteration": it, "cost": cost})


class ImageBatchCost(pyceres.CostFunction):
    """Python path: the observations of fixed ground points in one image (a fixed block of
    :mod:`solver.engine.residual_blocks`): residuals (2m) wrt the image block (and its camera's
    interior orientation and its pass when those are estimated)."""

    def __init__(self, rec: np.ndarray, pts: np.ndarray, sizes: list[int], control: SolveControl, tables):
        pyceres.CostFunction.__init__(self)
        self.img_tab, self.cam_tab = tables
        self.rec = rec
        self.pts = pts
        m = len(rec)
        self.scratch = tuple(np.zeros(2 * m * n) for n in sizes)
        self.control = control
        self.set_num_residuals(2 * m)
        self.set_parameter_block_sizes(list(sizes))

    def Evaluate(self, parameters, residuals, jacobians):  # noqa: N802 (Ceres API)
        if self.control.poll():
            return False
        if jacobians is None:
            return fixed_obs_block(self.rec, self.img_tab, self.cam_tab, self.pts, tuple(parameters), residuals, self.scratch, False)
        js = tuple(j if j is not None else s for j, s in zip(jacobians, self.scratch))
        return fixed_obs_block(self.rec, self.img_tab, self.cam_tab, self.pts, tuple(parameters), residuals, js, True)


class PointCost(pyceres.CostFunction):
    """Python path: all observations of one estimated ground point (a point block of
    :mod:`solver.engine.residual_blocks`): parameter blocks [point(3), images..., cameras..., passes...].

    The constants live in shared tables and short per-observation records; the kernel writes
    straight into Ceres' output arrays, so a call costs the trampoline plus one numba dispatch.
    """

    def __init__(self, rec: np.ndarray, sizes: list[int], control: SolveControl, tables):
        pyceres.CostFunction.__init__(self)
        self.img_tab, self.cam_tab = tables
        self.rec = rec
        k = len(rec)
        self.scratch = tuple(np.zeros(2 * k * n) for n in sizes)
        self.scratch_p = np.zeros(2 * k * 3)
        self.control = control
        self.set_num_residuals(2 * k)
        self.set_parameter_block_sizes([3] + list(sizes))

    def Evaluate(self, parameters, residuals, jacobians):  # noqa: N802 (Ceres API)
        if self.control.poll():
            return False
        if jacobians is None:
            return point_obs_block(self.rec, self.img_tab, self.cam_tab, parameters[0], tuple(parameters[1:]), residuals, self.scratch_p, self.scratch, False)
        jp = jacobians[0] if jacobians[0] is not None else self.scratch_p
        js = tuple(j if j is not None else s for j, s in zip(jacobians[1:], self.scratch))
        return point_obs_block(self.rec, self.img_tab, self.cam_tab, parameters[0], tuple(parameters[1:]), residuals, jp, js, True)


class ImageTermCost(pyceres.CostFunction):
    """Any term on one parameter block (:mod:`solver.engine.terms`): weighted states, line
    observations, camera priors, pass ephemeris observations, ..."""

    def __init__(self, term, nfree: int, control: SolveControl):
        pyceres.CostFunction.__init__(self)
        self.term = term
        self.control = control
        self.set_num_residuals(term.n_residuals)
        self.set_parameter_block_sizes([nfree])

    def Evaluate(self, parameters, residuals, jacobians):  # noqa: N802 (Ceres API)
        if self.control.poll():
            return False
        res, jac = self.term.evaluate(parameters[0])
        residuals[:] = res
        if jacobians is not None and jacobians[0] is not None:
            jacobians[0][:] = jac.ravel()
        return bool(np.all(np.isfinite(res)))


class _Callback(pyceres.IterationCallback):
    def __init__(self, control: SolveControl):
        pyceres.IterationCallback.__init__(self)
        self.control = control

    def __call__(self, summary):
        self.control.iteration(int(summary.iteration), float(summary.cost), bool(summary.step_is_successful))
        if self.control.poll() or self.control.statistically_converged:
            return pyceres.CallbackReturnType.SOLVER_TERMINATE_SUCCESSFULLY
        return pyceres.CallbackReturnType.SOLVER_CONTINUE


@dataclass
class SolveOutcome:
    iterations: int
    termination: str
    converged: bool
    usable: bool
    message: str
    initial_cost: float
    final_cost: float
    time_s: float
    linear_solver: str
    history: list[dict[str, float]] = field(default_factory=list)
    cancelled: bool = False
    timing_s: dict[str, float] = field(default_factory=dict)
    successful_steps: int = 0

    def unusable_reasons(self) -> list[str]:
        """Why the parameters this solve left are not a solution (empty: usable): Ceres
        reports the solution unusable (termination FAILURE), a cost is not finite, or no
        iteration succeeded without the start being already converged."""
        reasons = []
        if not self.usable:
            reasons.append(f"Ceres termination {self.termination}: {self.message}")
        for name, cost in (("initial", self.initial_cost), ("final", self.final_cost)):
            if not math.isfinite(cost):
                reasons.append(f"the {name} cost is not finite ({cost})")
        if self.successful_steps == 0 and self.termination != "CONVERGENCE":
            reasons.append(f"no successful iteration in {self.iterations}")
        return reasons


def _loss(options: SolveSettings) -> Any:
    if options.loss == "huber":
        return pyceres.HuberLoss(options.loss_scale)
    if options.loss == "cauchy":
        return pyceres.CauchyLoss(options.loss_scale)
    return None


@dataclass
class CeresProblem:
    """A Ceres problem built from an :class:`AdjustmentState` and the cost functions it
    references (they must outlive the solve); ``has_points``: estimated ground points (Schur);
    ``evaluator``: the compiled path's shared state (None on the Python path); ``python_blocks``:
    residual blocks evaluated in Python (with any, the solve uses one thread)."""

    problem: Any
    keep: list[Any]
    has_points: bool
    evaluator: Any = None
    python_blocks: int = 0
    blocks: list[tuple[Any, list[np.ndarray]]] = field(default_factory=list)

    def add(self, cost: Any, loss: Any, params: list[np.ndarray]) -> None:
        """Add a residual block (kept alive with the problem, listed in ``blocks``)."""
        self.keep.append(cost)
        self.blocks.append((cost, params))
        self.problem.add_residual_block(cost, loss, params)


def _add_parameter_blocks(cp: Any, problem: AdjustmentState) -> None:
    """Every block with free parameters of every kind before the eliminated one, in the
    registry's order (:mod:`solver.blocks.registry`; a shared block is one block); the points
    come with their residual blocks."""
    for kind in block_kinds.BLOCK_KINDS:
        if kind.eliminated:
            continue
        for block in kind.blocks(problem):
            if block.nfree:
                cp.add_parameter_block(block.params, block.nfree)


class _Compiled:
    """The compiled path's pieces for one problem: the extension, the shared evaluator, the
    context words and the callbacks' addresses (:mod:`solver.kernels.callbacks`)."""

    def __init__(self, native: Any, tables: tuple[np.ndarray, np.ndarray], out: CeresProblem):
        from solver.kernels import callbacks  # compiles or loads the C callbacks: compiled path only

        self.native = native
        self.cb = callbacks
        img_tab, cam_tab = tables
        self.evaluator = native.Evaluator(img_tab)
        ctx = np.zeros(callbacks.N_CONTEXT, dtype=np.int64)
        ctx[callbacks.C_IMG_ROWS], ctx[callbacks.C_IMG_COLS] = img_tab.shape
        ctx[callbacks.C_CAM_TAB] = cam_tab.ctypes.data
        ctx[callbacks.C_CAM_ROWS], ctx[callbacks.C_CAM_COLS] = cam_tab.shape
        self.context = ctx
        self.shared = (ctx, cam_tab)  # what every descriptor's context words point into
        out.keep += [ctx, cam_tab, img_tab]
        out.evaluator = self.evaluator

    def descriptors(self, blocks: ResidualBlocks, point: bool, data: np.ndarray | None = None) -> np.ndarray:
        """One descriptor row per block (layout ``B_*`` of :mod:`solver.kernels.callbacks`)."""
        cb = self.cb
        lead = 1 if point else 0
        nb = len(blocks)
        desc = np.zeros((nb, cb.B_HEADER + lead + blocks.sizes.shape[1]), dtype=np.int64)
        desc[:, cb.B_CONTEXT] = self.context.ctypes.data
        row_bytes = blocks.rec.shape[1] * blocks.rec.itemsize
        desc[:, cb.B_REC] = blocks.rec.ctypes.data + blocks.start[:-1] * row_bytes
        desc[:, cb.B_NREC] = np.diff(blocks.start)
        desc[:, cb.B_NSLOTS] = blocks.n_params
        desc[:, cb.B_MAXSIZE] = blocks.sizes.max(axis=1) if blocks.sizes.shape[1] else 0
        if data is not None:
            desc[:, cb.B_DATA] = data.ctypes.data + blocks.start[:-1] * data.shape[1] * data.itemsize
        if point:
            desc[:, cb.B_SIZES] = 3
        desc[:, cb.B_SIZES + lead :] = blocks.sizes
        return desc

    def cost(self, callback: Any, address: int, n_residuals: int, sizes: list[int], memory: Any) -> Any:
        """A cost function over the descriptor at ``address``; ``memory`` holds the arrays the
        descriptor points into (the cost function keeps it alive)."""
        return self.native.CallbackCost(self.evaluator, callback.address, address, n_residuals, sizes, memory)

    @staticmethod
    def row_addresses(desc: np.ndarray) -> list[int]:
        return (desc.ctypes.data + np.arange(len(desc)) * desc.strides[0]).tolist()


def _add_fixed_point_blocks(out: CeresProblem, problem: AdjustmentState, loss: Any, control: SolveControl, tables, compiled: _Compiled | None) -> None:
    """Observations of fixed ground points: one vectorised block per image."""
    blocks = fixed_blocks(problem)
    if len(blocks) == 0:
        return
    pts = fixed_points(problem, blocks)
    out.keep += [blocks.rec, pts]
    start = blocks.start.tolist()
    if compiled is not None:
        desc = compiled.descriptors(blocks, False, pts)
        out.keep.append(desc)
        addresses = compiled.row_addresses(desc)
        memory = (desc, blocks.rec, pts, compiled.shared)
    for b, (params, sizes) in enumerate(zip(blocks.params, blocks.param_sizes())):
        s, e = start[b], start[b + 1]
        if compiled is not None:
            cf = compiled.cost(compiled.cb.fixed_block_callback, addresses[b], 2 * (e - s), sizes, memory)
        else:
            cf = ImageBatchCost(blocks.rec[s:e], pts[s:e], sizes, control, tables)
            out.python_blocks += 1
        out.add(cf, loss, params)


SPLIT_RAYS = 3
"""Observations per residual block of a point in a large least-squares block (:func:`split_rays`)."""


def split_rays(problem: AdjustmentState, loss: Any) -> int | None:
    """The most observations of one point in one residual block: :data:`SPLIT_RAYS` for plain
    least squares with :data:`PARALLEL_MIN_RESIDUAL_BLOCKS` estimated points or more, else None
    (one block per point). Measured on the connected strip (docs/benchmarks.md): a point seen
    in six images as one block has each image's Jacobian cell zero-padded to all 12 rows, and
    Ceres stores and eliminates those zeros; in blocks of three the 300,000-observation solve
    took 14 % less CPU and 10 % less peak memory (same iterations and cost). Smaller jobs (every
    example) keep one block per point, their reports to the bit; a robust loss acts on each
    block's sum, so robust solves keep one block per point too."""
    if loss is not None or sum(p.estimated for p in problem.points) < PARALLEL_MIN_RESIDUAL_BLOCKS:
        return None
    return SPLIT_RAYS


def _add_point_blocks(out: CeresProblem, problem: AdjustmentState, loss: Any, control: SolveControl, tables, compiled: _Compiled | None) -> None:
    """Each estimated point: one block with all its observations (or several of at most
    :func:`split_rays` each), and the survey prior of a weighted control point once (Ceres'
    NormalPrior)."""
    blocks = point_blocks(problem, split_rays(problem, loss))
    if len(blocks) == 0:
        return
    out.has_points = True
    out.keep.append(blocks.rec)
    start = blocks.start.tolist()
    if compiled is not None:
        desc = compiled.descriptors(blocks, True)
        out.keep.append(desc)
        addresses = compiled.row_addresses(desc)
        memory = (desc, blocks.rec, compiled.shared)
    points = problem.points
    residuals = (2 * np.diff(blocks.start)).tolist()  # per block, as the sizes: no per-block numpy
    callback = compiled.cb.point_block_callback if compiled is not None else None
    owners = blocks.owner.tolist()
    for b, (point_index, params, sizes) in enumerate(zip(owners, blocks.params, blocks.param_sizes())):
        p = points[point_index]
        if compiled is not None:
            cf = compiled.cost(callback, addresses[b], residuals[b], [3] + sizes, memory)
        else:
            cf = PointCost(blocks.rec[start[b] : start[b + 1]], sizes, control, tables)
            out.python_blocks += 1
        out.add(cf, loss, [p.xyz] + params)
        first_of_point = b == 0 or owners[b - 1] != point_index  # a split point's survey prior once
        if first_of_point and p.role == "gcp" and p.sigma_m is not None and p.known_lgs is not None:
            out.add(pyceres.factors.NormalPrior(p.known_lgs.copy(), np.diag(p.sigma_m**2)), None, [p.xyz])


def _add_family_blocks(out: CeresProblem, problem: AdjustmentState, control: SolveControl, compiled: _Compiled | None) -> None:
    """The observation families' terms (:mod:`solver.engine.terms`), each on its parameter block.
    On the compiled path a linear term is a ``LinearCost`` and a term with a compiled form (the
    pass states, the straight lines) a C callback; a term with neither (a family added without
    one) stays a Python cost function there, and a problem with any such term is solved on one
    thread."""
    for labelled in family_terms(problem):
        owner = block_owner(problem, labelled)
        linear = getattr(labelled.term, "linear_form", None)  # both optional in the Term interface
        native_form = getattr(labelled.term, "compiled_form", None)
        form = linear() if compiled is not None and linear is not None else None
        if form is not None:
            a, b = form
            cf = compiled.native.LinearCost(compiled.evaluator, a, b)
        elif compiled is not None and native_form is not None:
            name, desc, arrays = native_form()
            cf = compiled.cost(getattr(compiled.cb, name), desc.ctypes.data, labelled.term.n_residuals, [owner.nfree], (desc, arrays))
        else:
            cf = ImageTermCost(labelled.term, owner.nfree, control)
            out.python_blocks += 1
        robust = getattr(labelled.term, "loss", None)  # optional: a family's own robust loss (DEM heights)
        out.add(cf, _term_loss(robust()) if robust is not None else None, [owner.params])


def _term_loss(spec: tuple[str, float] | None) -> Any:
    """A term's robust loss from its ``(name, scale)`` (whitened units): "huber", "cauchy", or
    None / "none" for plain least squares."""
    if spec is None or spec[0] == "none":
        return None
    return pyceres.HuberLoss(spec[1]) if spec[0] == "huber" else pyceres.CauchyLoss(spec[1])


def build_ceres_problem(problem: AdjustmentState, options: SolveSettings, control: SolveControl) -> CeresProblem:
    """The Ceres problem of ``problem``: parameter blocks, then residual blocks (module doc),
    compiled where the extension is available (:mod:`solver.engine.native`)."""
    out = CeresProblem(pyceres.Problem(), [], False)
    tables = (image_table(problem), camera_table(problem))
    native_module = native.module()
    compiled = _Compiled(native_module, tables, out) if native_module is not None else None
    _add_parameter_blocks(out.problem, problem)
    loss = _loss(options)
    _add_fixed_point_blocks(out, problem, loss, control, tables, compiled)
    _add_point_blocks(out, problem, loss, control, tables, compiled)
    _add_family_blocks(out, problem, control, compiled)
    return out


PARALLEL_MIN_RESIDUAL_BLOCKS = 2000
"""Fewer residual blocks than this are evaluated on one thread: threads gain nothing there, and
Ceres sums the cost and gradient of the threads' shares in the order they finish, so a threaded
solve's last digits (relative 1e-9 in sigmas, the iteration at which a tolerance is met) can
change from run to run. Small jobs stay reproducible to the bit; large ones gain the cores."""


def solve_threads(built: CeresProblem) -> int:
    """Threads of the solve: Python cost functions take the GIL (more threads only contend) and
    an exception inside one with several threads ends the process, so one thread unless every
    block is compiled and there are enough of them (:data:`PARALLEL_MIN_RESIDUAL_BLOCKS`)."""
    if built.evaluator is None or built.python_blocks or len(built.blocks) < PARALLEL_MIN_RESIDUAL_BLOCKS:
        return 1
    return native.solver_threads()


NONMONOTONIC_MIN_RESIDUAL_BLOCKS = PARALLEL_MIN_RESIDUAL_BLOCKS
"""Residual blocks from which the solve takes non-monotonic steps (Ceres' ``use_nonmonotonic_steps``:
a step is judged against the lowest cost of the last few iterations, so the trust region can
grow while the cost wanders up for a step or two; Ceres returns the best parameters seen).
Large blocks whose images have no weighted state sit in a curved valley (pitch against
along-track position, docs/models.md section 7) where monotonic Levenberg-Marquardt creeps:
its ratio of actual to predicted decrease stays near 0.5, so the trust region neither grows nor
shrinks and every step gains ~0.01 of chi-square. Measured (docs/benchmarks.md): the
60-image block without weighted states, 51 iterations not converged -> 15, converged at a
lower cost (the C++ reference from the same start: the same 15); the 9-image connected strip
without states, 51 not converged -> 42 converged (the reference: 41). Blocks with weighted
states take the same path either way (GN steps are accepted at once). Smaller jobs keep the
monotonic path (their reports, iteration counts included, are the fixtures')."""


def nonmonotonic(built: CeresProblem) -> bool:
    """Whether the solve of ``built`` takes non-monotonic steps (:data:`NONMONOTONIC_MIN_RESIDUAL_BLOCKS`)."""
    return len(built.blocks) >= NONMONOTONIC_MIN_RESIDUAL_BLOCKS


def ceres_options(options: SolveSettings, built: CeresProblem, control: SolveControl) -> Any:
    """A fresh ``pyceres.SolverOptions`` (assigning callbacks to a used one appends) for
    ``options``; the iteration callback is kept alive with ``built``'s cost functions."""
    so = pyceres.SolverOptions()
    so.max_num_iterations = options.max_iterations
    so.function_tolerance = options.function_tolerance
    so.parameter_tolerance = options.parameter_tolerance
    so.gradient_tolerance = 1e-14
    # Start close to Gauss-Newton: the problems are well initialised but ill-conditioned (pitch vs
    # along-track position), and a small initial trust region makes LM creep for tens of
    # iterations along those directions (41 -> 6 iterations on a triplet). Rejected steps still
    # shrink the region when the start is poor.
    so.initial_trust_region_radius = 1e12
    so.use_nonmonotonic_steps = nonmonotonic(built)
    so.num_threads = solve_threads(built)
    so.logging_type = pyceres.LoggingType.SILENT
    so.minimizer_progress_to_stdout = False
    if built.has_points:
        # measured on connected strips (docs/benchmarks.md, bench/bench_linear_solver.py):
        # DENSE_SCHUR takes the same steps and is no faster at 100k-300k observations, its dense
        # factor grows with the cube of the image parameters; ITERATIVE_SCHUR (Schur-Jacobi or
        # cluster preconditioners) needs 3-5x the iterations on these ill-conditioned blocks
        so.linear_solver_type = pyceres.LinearSolverType.SPARSE_SCHUR
    else:
        so.linear_solver_type = pyceres.LinearSolverType.DENSE_QR
    so.update_state_every_iteration = False
    callback = _Callback(control)
    built.keep.append(callback)
    so.callbacks = [callback]
    return so


def summarise(summary: Any, control: SolveControl, time_s: float) -> SolveOutcome:
    """The solve's outcome in the library's terms (:class:`SolveOutcome`) from Ceres' summary."""
    term = str(summary.termination_type).split(".")[-1]
    usable = bool(summary.IsSolutionUsable())
    converged = term == "CONVERGENCE" or (term == "USER_SUCCESS" and control.statistically_converged)
    message = str(summary.message)
    if control.statistically_converged and term == "USER_SUCCESS":
        term = "CONVERGENCE"
        message = f"chi-square changed by less than {SolveControl.CHI2_TOLERANCE} in two successive iterations"
    return SolveOutcome(
        iterations=int(summary.num_successful_steps + summary.num_unsuccessful_steps),
        # Ceres counts the evaluation at the start (iteration 0) as a successful step
        successful_steps=max(int(summary.num_successful_steps) - 1, 0),
        termination=term,
        converged=converged,
        usable=usable,
        message=message,
        initial_cost=float(summary.initial_cost),
        final_cost=float(summary.final_cost),
        time_s=time_s,
        linear_solver=str(summary.linear_solver_type_used).split(".")[-1],
        history=list(control.history),
        cancelled=control.cancelled,
        timing_s={
            "residual_evaluation": float(summary.residual_evaluation_time_in_seconds),
            "jacobian_evaluation": float(summary.jacobian_evaluation_time_in_seconds),
            "linear_solver": float(summary.linear_solver_time_in_seconds),
            "preprocessor": float(summary.preprocessor_time_in_seconds),
        },
    )


@contextmanager
def _cancel_watch(control: SolveControl, evaluator: Any) -> Iterator[None]:
    """On the compiled path no Python runs inside an evaluation: a thread polls the cancel hook
    while Ceres works (pyceres releases the GIL) and raises the evaluator's flag, after which
    every compiled cost function fails its evaluation and the iteration callback stops the solve."""
    if evaluator is None or control.cancel is None:
        yield
        return
    done = threading.Event()

    def watch() -> None:
        while not done.wait(control.poll_interval_s):
            if control.poll():
                evaluator.cancel()
                return

    thread = threading.Thread(target=watch, name="pba-cancel-watch", daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()


def evaluation_path() -> str:
    """"compiled" or "python": how this process evaluates residual blocks (:mod:`solver.engine.native`)."""
    return native.status().path


def solve(problem: AdjustmentState, options: SolveSettings, control: SolveControl) -> SolveOutcome:
    """Build the Ceres problem from ``problem``, set the options, solve (parameters updated in
    place), summarise."""
    t0 = time.perf_counter()
    built = build_ceres_problem(problem, options, control)
    so = ceres_options(options, built, control)
    summary = pyceres.SolverSummary()
    with _cancel_watch(control, built.evaluator):
        pyceres.solve(so, built.problem, summary)
    block_kinds.refresh(problem)  # what the kinds derive from their parameters (the pass trajectories) for the final values
    outcome = summarise(summary, control, time.perf_counter() - t0)
    del built, so, summary
    # the Ceres problem of a large job (residual blocks, cost functions, Jacobian and Schur
    # buffers: about 1.6 GB at a million observations), much of it freed in the solver threads'
    # heaps (about 640 MB at a million observations), where the report could not reuse it and
    # raised the peak above the solve's (bench/bench_scale.py --memory)
    release_freed_memory()
    return outcome



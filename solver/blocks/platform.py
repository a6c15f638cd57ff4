"""The images' platform parameters as parameter blocks (kind ``image``).

Each image's free platform parameters (its model's free coefficients, :class:`solver.state.ImageState`
``free_idx``) form one block, except that images sharing an attitude share one: pass images
with the model option ``attitude: camera`` (the default) share one block per (pass, camera).
:func:`attitude_blocks` is the one statement of that rule: assembly shares the block by it,
validation counts and checks by it, and measured attitude attaches to it
(:mod:`solver.observations.attitude`). A shared block is one :class:`PlatformBlock` listing its
images; each image points to its block (``ImageState.platform``).

Terms label this kind ``image`` with an image's index (the block of that image).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from solver.blocks.kind import BlockDefaults
from solver.blocks.platform_values import initial_platform_values
from solver.errors import Problem
from solver.geometry.geodesy import A_WGS84_M, E2_WGS84, LocalFrame
from solver.kernels.layout import KC_ATT_BASE, N_KEPLER_CONST
from solver.platforms import HELD, PlatformModel, get_model
from solver.platforms.kepler import AE_M, GM_M3_S2, J2, OMEGA_RAD_S
from solver.schema.job import Camera

if TYPE_CHECKING:  # pragma: no cover
    from solver.schema.job import Image, Job
    from solver.schema.settings import BlockConfig
    from solver.state import AdjustmentState, ImageState

DEFAULT_PASS = "1"
ATTITUDE_MODES = ("camera", "image")  # model option "attitude": one set per camera of a pass / per image


def pass_id(options: dict) -> str:
    """The pass of a pass-propagated image (model option ``pass``)."""
    return str(options.get("pass", DEFAULT_PASS))


def attitude_mode(options: dict) -> str:
    """Model option ``attitude`` of a pass image: ``camera`` (shared per pass and camera) or ``image``."""
    return str(options.get("attitude", ATTITUDE_MODES[0]))


@dataclass
class PlatformBlock:
    """The platform parameters of one image, or of the images sharing an attitude (``images``,
    the first one names the block); ``params``: the free coefficients (internal units)."""

    index: int
    images: list[int]
    params: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def nfree(self) -> int:
        return int(self.params.shape[0])


def kepler_constants(model: PlatformModel, frame: LocalFrame, mounting_pitch_deg: float = 0.0) -> np.ndarray:
    kc = np.zeros(N_KEPLER_CONST)
    kc[16] = math.radians(mounting_pitch_deg)
    kc[0:9] = frame.rotation_ecef_to_lgs.ravel()
    kc[9:12] = frame.origin_ecef_m
    kc[12] = GM_M3_S2
    kc[13] = OMEGA_RAD_S
    kc[14] = J2 if model.j2 else 0.0
    kc[15] = AE_M
    return kc


def rpc_constants(image: Image, frame: LocalFrame) -> np.ndarray:
    """kc of an RPC image (layout in :mod:`solver.kernels.rpc`): frame, ellipsoid, and the RPC
    converted to our pixel convention (the one place where ``pixel_convention`` is applied)."""
    from solver.geometry.rpc import RPC  # here: validation imports this module in the API process (no numba)
    from solver.kernels.rpc import KC_A, KC_E2, RPC_LEN, RPC_START
    rpc = RPC.from_job(image.rpc.model_dump(mode="json"))
    kc = np.zeros(RPC_START + RPC_LEN)
    kc[0:9] = frame.rotation_ecef_to_lgs.ravel()
    kc[9:12] = frame.origin_ecef_m
    kc[KC_A] = A_WGS84_M
    kc[KC_E2] = E2_WGS84
    r = kc[RPC_START:]
    r[0:10] = (
        rpc.line_off, rpc.samp_off, rpc.lat_off, rpc.long_off, rpc.height_off,
        rpc.line_scale, rpc.samp_scale, rpc.lat_scale, rpc.long_scale, rpc.height_scale,
    )
    r[10:90] = np.concatenate([rpc.line_num, rpc.line_den, rpc.samp_num, rpc.samp_den])
    return kc


def platform_constants(model: PlatformModel, image: "Image", frame: LocalFrame, cameras: dict[str, Camera]) -> tuple[Camera | None, np.ndarray, float]:
    """(camera, constants ``kc``, tau per line) of an image's platform model: a kind with a
    camera has its camera, the frame, the orbit constants and its time scale; a kind without
    (an RPC image) the RPC and the frame, no camera."""
    if not model.kind.has_camera:  # the RPC and the frame are the image's constants
        return None, rpc_constants(image, frame), 0.0
    cam = cameras[image.camera]
    return cam, kepler_constants(model, frame, cam.mounting_pitch_deg), model.tau_per_line(cam.line_time_s or 0.0)


def _attitude_blocks(entries) -> list[list[int]]:
    """Positions of the images of each shared attitude block, from (model or None, model
    options, camera id) per image: an orbit-attitude or pass image alone, except that pass
    images with ``attitude: camera`` share one block per (pass, camera)."""
    blocks: dict[tuple, list[int]] = {}
    for i, (model, options, camera) in enumerate(entries):
        if model is None or not model.kind.attitude_in_orbital_frame:
            continue
        if model.kind.shares_pass_orbit and attitude_mode(options) == "camera":
            key: tuple = ("camera", pass_id(options), camera)
        else:
            key = ("image", i)
        blocks.setdefault(key, []).append(i)
    return list(blocks.values())


def _model_or_none(name: str):
    try:
        return get_model(name)
    except KeyError:
        return None


def attitude_blocks(job: "Job") -> list[list[int]]:
    """:func:`_attitude_blocks` of the job's images with the models the document names."""
    return _attitude_blocks((_model_or_none(im.model.name), im.model.options, im.camera) for im in job.images)


def image_attitude_blocks(images: list["ImageState"]) -> list[list[int]]:
    """:func:`_attitude_blocks` of a problem's images (with the models actually adjusted,
    which a model comparison may override)."""
    return _attitude_blocks((img.model, img.options, img.camera.id if img.camera else None) for img in images)


def attitude_time_offset(img: "ImageState") -> float:
    """Time (tau units) added to the image's tau to give the time of its angle polynomials (pass
    images sharing a camera's attitude: the time since the pass reference epoch)."""
    return img.model.kind.attitude_time_offset(img.kc)


def attitude_base_problems(im: "Image", i: int, model: PlatformModel) -> list[Problem]:
    """Validation of an image's ``attitude_base``: a model whose angles are relative to the
    orbital frame, the image's first line time, two samples at least at increasing epochs."""
    base = im.attitude_base
    if not base:
        return []
    loc = ("images", i, "attitude_base")
    if not model.kind.attitude_in_orbital_frame:
        return [Problem("attitude_needs_orbital_frame",
                        f"image {im.id!r}: attitude_base is roll, pitch and yaw relative to the orbital frame, but model "
                        f"{model.name} has Earth-fixed angles; use an orbit-attitude (OA-*) or pass (PASS-*) model", loc)]
    if im.first_line_time_s is None:
        return [Problem("attitude_needs_epoch", f"image {im.id!r}: attitude_base needs the image's first_line_time_s",
                        ("images", i, "first_line_time_s"))]
    if len(base) < 2:
        return [Problem("attitude_base_too_short", f"image {im.id!r}: attitude_base needs two samples at least (it is "
                        "interpolated between them)", loc)]
    for k in range(1, len(base)):
        if not base[k].time_s > base[k - 1].time_s:
            return [Problem("attitude_base_not_increasing", f"image {im.id!r}: attitude_base sample {k} "
                            f"(time_s {base[k].time_s}) is not after the one before it; epochs must increase", (*loc, k, "time_s"))]
    return []


def attach_attitude_base(problem: "AdjustmentState") -> None:
    """Append each image's ``attitude_base`` to its constants ``kc`` (after the pass segment:
    assembly calls this once the blocks are built) and point ``kc[KC_ATT_BASE]`` at it: its
    sample count, their times in the angle polynomials' time (s since the image's first line,
    plus :func:`attitude_time_offset`), then roll, pitch and yaw (rad). Images without one, or
    whose adjusted model's angles are not relative to the orbital frame (a model comparison's
    override), keep no base."""
    for img in problem.images:
        base = problem.job.images[img.index].attitude_base
        if not base or img.model is None or not img.model.kind.attitude_in_orbital_frame:
            continue
        t0 = problem.job.images[img.index].first_line_time_s
        times = np.array([s.time_s for s in base], float) - t0 + attitude_time_offset(img)
        ang = np.radians(np.array([[s.roll_deg, s.pitch_deg, s.yaw_deg] for s in base], float))
        table = np.concatenate([[float(len(base))], times, ang[:, 0], ang[:, 1], ang[:, 2]])
        kc = np.concatenate([img.kc, table])
        kc[KC_ATT_BASE] = float(img.kc.shape[0])
        img.kc = kc


def attitude_base_at(img: "ImageState", times_s: np.ndarray) -> np.ndarray:
    """(n, 3) roll, pitch, yaw (rad) of an image's attitude base at the angle polynomials'
    times ``times_s`` (zeros without a base), by the kernels' own interpolation."""
    from solver.kernels.platform import _attitude_base_into  # numba: validation never comes here

    out = np.zeros((len(times_s), 3))
    rate = np.zeros(3)
    kc = np.ascontiguousarray(img.kc, dtype=float)
    for k, t in enumerate(np.asarray(times_s, float)):
        _attitude_base_into(kc, float(t), out[k], rate)
    return out


def attitude_groups(problem: "AdjustmentState") -> dict[int, list[str]]:
    """Image index -> ids of all images sharing its platform block (only where shared by 2+)."""
    out = {}
    for block in problem.blocks.get("image", []):
        if len(block.images) > 1:
            for i in block.images:
                out[i] = [problem.images[k].id for k in block.images]
    return out


def orders_ok(model, options) -> bool:
    """Whether the model accepts these options' orders."""
    try:
        model.effective_orders(options)
        return True
    except ValueError:
        return False


def _shared_attitude_problems(job: "Job") -> list[Problem]:
    """Images sharing one attitude block (:func:`attitude_blocks`) must ask for the same model
    orders and give the same initial values as the block's first image."""

    def signature(i: int):
        im = job.images[i]
        model = get_model(im.model.name)
        orders = model.effective_orders(im.model.options) if orders_ok(model, im.model.options) else None
        return orders, model.name

    out = []
    for block in attitude_blocks(job):
        lead = job.images[block[0]]
        for i in block[1:]:
            im = job.images[i]
            pid = pass_id(im.model.options)
            if signature(i) != signature(block[0]):
                out.append(
                    Problem(
                        "inconsistent_attitude_group",
                        f"image {im.id!r} shares the attitude of camera {im.camera!r} on pass {pid!r} with "
                        f"image {lead.id!r} but asks for other orders; give them the "
                        "same orders or use the option attitude: image",
                        ("images", i, "model", "options"),
                    )
                )
                continue
            clash = sorted(n for n in set(lead.initial) & set(im.initial) if lead.initial[n] != im.initial[n])
            if clash:
                out.append(
                    Problem(
                        "inconsistent_attitude_group",
                        f"image {im.id!r} shares the attitude of camera {im.camera!r} on pass {pid!r} with "
                        f"image {lead.id!r} but gives other initial values for "
                        f"{', '.join(clash)}; give one value (or use the option attitude: image)",
                        ("images", i, "initial"),
                    )
                )
    return out


def _shared_unknowns(job: "Job") -> int:
    """The parameters that images sharing an attitude block have in common, counted once per
    image by the validation's per-image count and here taken off again (zero or negative)."""

    def valid(i: int):
        im = job.images[i]
        model = _model_or_none(im.model.name)
        return model if model is not None and orders_ok(model, im.model.options) else None

    n = 0
    for block in attitude_blocks(job):
        members = [i for i in block if valid(i) is not None]
        if len(members) > 1:
            lead = members[0]
            n -= (len(members) - 1) * len(valid(lead).parameters(job.images[lead].model.options))
    return n


def model_option_problems(model: PlatformModel, options: dict[str, Any], loc: tuple) -> list[Problem]:
    """Options the model does not take, orders of elements it does not order, a held position,
    or nothing left to estimate (``loc`` is the image's ``model``)."""
    out = [
        Problem(
            "invalid_model_options",
            f"model {model.name} has no option {key!r}"
            + (f" (its options: {', '.join(sorted(model.option_names))})" if model.option_names else ""),
            (*loc, "options", key),
        )
        for key in options
        if key not in model.option_names
    ]
    orders = options.get("orders") or {}
    for e, order in orders.items():
        if e not in model.order_elements():
            out.append(
                Problem(
                    "invalid_model_options",
                    f"model {model.name} takes orders of {', '.join(model.order_elements())} only",
                    (*loc, "options", "orders", e),
                )
            )
        elif e in ("X", "Y", "Z") and order == HELD:
            out.append(
                Problem(
                    "invalid_model_options",
                    f"the position element {e} cannot be held (order -1 holds an angle at <angle>_deg)",
                    (*loc, "options", "orders", e),
                )
            )
    if not out and not model.kind.shares_pass_orbit and not model.parameters(options):
        out.append(
            Problem(
                "invalid_model_options",
                f"model {model.name} with these orders estimates no parameter",
                (*loc, "options", "orders"),
            )
        )
    return out


def rpc_image_problems(job: Job, im: Image, i: int, model: PlatformModel) -> list[Problem]:
    """Problems of an image with an RPC or an RPC bias model: both or neither; an RPC image has
    no camera, platform data, lines or self-calibration; its RPC must be usable (non-zero scales,
    non-zero constant denominator terms); ``initial`` and ``bias_prior`` name its parameters."""
    loc = ("images", i)
    if model.kind.has_camera:
        return [Problem("rpc_with_rigorous_model", f"image {im.id!r} has an rpc but the rigorous model {model.name}; "
                        "use an RPC bias model (RPC-SHIFT, RPC-DRIFT, RPC-AFFINE) or leave rpc out", loc + ("rpc",))]
    if im.rpc is None:
        return [Problem("missing_rpc", f"image {im.id!r}: model {model.name} needs images[].rpc (an RPC00B)", loc + ("rpc",))]
    out = []
    for name in ("camera", "approx_state", "first_line_time_s", "ephemeris", "attitude"):
        if getattr(im, name):
            out.append(Problem("not_for_rpc_image", f"image {im.id!r} is an RPC image: {name} does not apply "
                               "(the RPC is its whole sensor model)", loc + (name,)))
    for name in ("line_scale", "samp_scale", "lat_scale", "long_scale", "height_scale"):
        if getattr(im.rpc, name) == 0:
            out.append(Problem("invalid_rpc", f"image {im.id!r}: rpc {name} is 0", loc + ("rpc", name)))
    for name in ("line_den_coeff", "samp_den_coeff"):
        if getattr(im.rpc, name)[0] == 0:
            out.append(Problem("invalid_rpc", f"image {im.id!r}: the constant term of rpc {name} is 0", loc + ("rpc", name, 0)))
    names = {p.name for p in model.parameters({})}
    for name in ("initial", "bias_prior"):
        unknown = sorted(set(getattr(im, name)) - names)
        if unknown:
            out.append(Problem("unknown_parameter", f"image {im.id!r}: model {model.name} has no parameter(s) "
                               f"{', '.join(unknown)}", loc + (name, unknown[0])))
    if model.options_doc == {} and im.model.options:
        out.append(Problem("invalid_model_options", f"image {im.id!r}: model {model.name} takes no options", loc + ("model", "options")))
    for k, ln in enumerate(job.lines):
        if any(o.image == im.id for o in ln.observations):
            out.append(Problem("not_for_rpc_image", f"line {ln.id!r} is observed in RPC image {im.id!r}: line observations "
                               "need a rigorous model (their condition uses the projection centre and the image ray)",
                               ("lines", k, "observations")))
    return out


def image_problems(job: "Job", i: int, cameras: dict[str, Any], state_of: Callable[[], Any]) -> tuple[list[Problem], Any, int | None]:
    """Validation of image ``i``'s platform block: its model, options, initial values, its RPC
    (RPC images) and, for a model that takes its position from the image's state, an initial
    position (``state_of()``: its approximate state or None). Returns (problems, the model or
    None, its number of parameters or None when they cannot be counted)."""
    im = job.images[i]
    problems: list[Problem] = []
    try:
        model = get_model(im.model.name)
    except KeyError as exc:
        return [Problem("unknown_model", str(exc.args[0]), ("images", i, "model", "name"))], None, None
    if not model.kind.has_camera or im.rpc is not None:
        rpc_issues = rpc_image_problems(job, im, i, model)
        return rpc_issues, model, None if rpc_issues else len(model.parameters({}))
    if im.camera not in cameras:
        problems.append(
            Problem("unknown_camera", f"image {im.id!r} uses unknown camera {im.camera!r}", ("images", i, "camera"))
        )
    option_problems = model_option_problems(model, im.model.options, ("images", i, "model"))
    if option_problems:
        return problems + option_problems, model, None
    try:
        params = model.parameters(im.model.options)
    except ValueError as exc:
        return problems + [Problem("invalid_model_options", str(exc), ("images", i, "model", "options"))], model, None
    names = {p.name for p in params}
    unknown = sorted(set(im.initial) - names)
    if unknown:
        problems.append(
            Problem(
                "unknown_parameter",
                f"image {im.id!r}: model {model.name} has no parameter(s) {', '.join(unknown)}",
                ("images", i, "initial"),
            )
        )
    problems += attitude_base_problems(im, i, model)
    if model.kind.position_from_image_state and state_of() is None and not {"X0", "Y0", "Z0"} <= set(im.initial):
        problems.append(
            Problem(
                "no_initial_position",
                f"image {im.id!r} needs approx_state (position/velocity at line 0), an ephemeris "
                "covering first_line_time_s, or initial values for X0, Y0, Z0 (and the other "
                "position terms)",
                ("images", i, "approx_state"),
            )
        )
    return problems, model, len(params)


class ImageKind(BlockDefaults):
    """The images' platform parameters: one block per image or per shared attitude. This kind
    checks, builds, shares, counts, initialises (:mod:`solver.blocks.platform_values`) and names
    them; they are reported with the images (the report's ``images`` section, the core's)."""

    name = "image"

    def check(self, job: "Job") -> tuple[list[Problem], int]:
        """The shared attitude blocks: consistent images, and their common parameters counted
        once (validation counts each image's parameters with the image)."""
        issues = _shared_attitude_problems(job)
        return issues, 0 if issues else _shared_unknowns(job)

    def build(self, problem: "AdjustmentState", config: "BlockConfig") -> list[PlatformBlock]:
        shared = {i: block for block in image_attitude_blocks(problem.images) for i in block}
        out: list[PlatformBlock] = []
        for img in problem.images:
            members = shared.get(img.index, [img.index])
            if members[0] != img.index:  # the block of an earlier image
                img.platform = problem.images[members[0]].platform
                continue
            img.platform = PlatformBlock(len(out), list(members), np.zeros(img.free_idx.shape[0]))
            out.append(img.platform)
        return out

    def addressed(self, problem: "AdjustmentState") -> list[Any]:
        return [img.platform for img in problem.images]

    def initialise(self, problem: "AdjustmentState", states: dict[int, Any]) -> list[Problem]:
        """Position from the approximate states, attitude by resection (:mod:`solver.blocks.platform_values`)."""
        return initial_platform_values(problem, states)

    def names(self, problem: "AdjustmentState") -> list[str]:
        out = []
        for block in self.blocks(problem):
            img = problem.images[block.images[0]]  # a shared block is named after its first image
            out += [f"{img.id}/{p.name}" for p in img.model.parameters(img.options)]
        return out


KIND = ImageKind()

"""``pba simulate PRESET [options] -o job.json``: write a simulated job and its truth file."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from solver.geometry.rpc import BIAS_MODELS
from solver.simulate import presets
from solver.simulate.camera import PRISM_LAYOUTS
from solver.simulate.lines import cbers_lines
from solver.simulate.rpc import RpcSettings, RpcSettingsError, parse_bias
from solver.simulate.scene import SceneSettings, write_documents

RPC_MODELS = tuple(BIAS_MODELS)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", required=True, help="job document to write (JSON)")
    p.add_argument("--truth", help="truth file to write (default: <output stem>.truth.json beside it)")
    p.add_argument("--seed", type=int, default=1, help="random seed (same seed, same documents)")
    p.add_argument("--model", default="K2", help="platform model written for every image (default K2)")
    p.add_argument("--noise-px", type=float, default=0.5, help="image measurement sigma, pixels (default 0.5)")
    p.add_argument("--gcp-sigma-m", type=float, default=0.2, help="survey sigma of gcp/check, metres (default 0.2)")
    p.add_argument("--name", help="job name")
    p.add_argument("--truth-step", type=int, default=100, help="truth samples every N lines (default 100)")
    p.add_argument("--jitter-rad", type=float, default=0.0, help="attitude jitter amplitude sigma, rad (default 0)")
    p.add_argument("--indent", type=int, default=None, help="pretty-print the JSON")
    p.add_argument(
        "--attitude-noise-deg",
        type=float,
        default=0.002,
        help="noise of the attitude samples written with each image, deg (default 0.002)",
    )
    p.add_argument(
        "--weight-ephemeris",
        metavar="SIGMA_M,SIGMA_M_S",
        help="write options.ephemeris with these position / velocity sigmas (e.g. 10,0.05): "
        "the simulated state vectors become weighted observations",
    )
    p.add_argument(
        "--weight-attitude",
        metavar="SIGMA_DEG",
        type=float,
        help="write options.attitude with this sigma for roll, pitch and yaw: the simulated "
        "attitude samples become weighted observations (orbit-attitude and pass models)",
    )
    p.add_argument(
        "--iop-errors",
        default="none",
        help="interior-orientation errors of the simulated cameras: none (default), default "
        "(df ~2 mm, chip shifts 0.02-0.03 mm on the non-master chips, a few ppm of a1/b1), or a "
        "JSON file {camera id: {name: value}} with the names of docs/models.md section 8",
    )
    p.add_argument(
        "--rpc-model",
        choices=RPC_MODELS,
        help="make images RPC images with this bias model: the job gets images[].rpc (the RPC00B fitted "
        "to the true geometry plus --rpc-bias) and no camera for them; multi-chip cameras are measured in "
        "their chip-aligned ideal image; the truth file's rpc_images has the bias and the fit residuals",
    )
    p.add_argument(
        "--rpc-bias",
        metavar="NAME=VALUE,...",
        default="",
        help="the known bias the delivered RPCs carry (observed = RPC + bias), e.g. "
        "'a0=20,b0=-12,a_line=1e-4'; names a0, a_line, a_column, b0, b_line, b_column (px, px/px); default none",
    )
    p.add_argument(
        "--rpc-images",
        metavar="N,N,...",
        help="only these images (1-based, in the job's order) are RPC images, the others keep their "
        "camera and --model (a mixed block); default every image",
    )
    p.add_argument(
        "--raster",
        action="store_true",
        help="also write each image's synthetic raster (textured ground, a bright target at every "
        "control and check point): <output stem>.<image id>.tif, raw image geometry",
    )
    p.add_argument(
        "--raster-texture",
        choices=("smooth", "rich"),
        default="smooth",
        help="smooth (default: sines, 8-bit) or rich: a fine random ground texture and per-image gain, offset "
        "and noise, 16-bit (for image matching, pba match)",
    )


def _chip_layout(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--chip-layout",
        choices=PRISM_LAYOUTS,
        default="partition",
        help="PRISM CCD chips: partition (default: four chips side by side over the 14496 columns) or "
        "butted (the real focal-plane chips of 4992 / 4928 columns overlapping by 32, the outer ones "
        "extending beyond the image; seed 001 section 3)",
    )


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``simulate`` and its presets to the ``pba`` command line."""
    sim = subparsers.add_parser("simulate", help="simulate a scene: job document + truth file")
    sub = sim.add_subparsers(dest="preset", metavar="PRESET", required=True)

    p = sub.add_parser("prism-single", help="one PRISM-like image (seed 000)")
    _common(p)
    p.add_argument("--camera", choices=presets.PRISM_VIEWS, default="nadir")
    p.add_argument("--gcps", type=int, default=14, help="control points (default 14)")
    p.add_argument("--checks", type=int, default=9, help="check points (default 9)")
    _chip_layout(p)

    p = sub.add_parser("prism-triplet", help="PRISM-like backward/nadir/forward triplet (seed 001)")
    _common(p)
    p.add_argument("--gcps", type=int, default=22, help="control points (default 22)")
    p.add_argument("--checks", type=int, default=20, help="check points (default 20)")
    p.add_argument("--tie-points", type=int, default=40, help="tie points, each seen by all three images (default 40)")
    _chip_layout(p)

    p = sub.add_parser("cbers-scene", help="CBERS-like CCD scene, SAD69 / UTM 22S (seed 002)")
    _common(p)
    p.add_argument("--gcps", type=int, default=23, help="control points (default 23)")
    p.add_argument("--checks", type=int, default=8, help="check points (default 8)")

    p = sub.add_parser("cbers-lines", help="CBERS-like scene with road segments as control lines (seed 002)")
    _common(p)
    p.add_argument("--lines", type=int, default=50, help="control lines (road segments)")
    p.add_argument("--check-lines", type=int, default=0, help="check lines")
    p.add_argument("--gcps", type=int, default=23, help="control points (default 23)")
    p.add_argument("--checks", type=int, default=8, help="check points (default 8)")
    p.add_argument("--line-noise-px", type=float, default=0.3, help="sigma of the lines' image points (default 0.3)")
    p.add_argument("--yaw-steering", action="store_true", help="yaw-steer the platform (default: no, as CBERS)")

    p = sub.add_parser("strip", help="N consecutive PRISM triplets along one pass")
    _common(p)
    p.add_argument("--triplets", type=int, default=20, help="consecutive triplets along the pass (default 20)")
    p.add_argument("--tie-points", type=int, default=30000, help="tie points in total")
    p.add_argument("--gcps", type=int, default=None, help="gcps in total (default 4 per triplet)")
    p.add_argument("--checks", type=int, default=None, help="check points in total (default 2 per triplet)")

    p = sub.add_parser("small-triplet", help="small backward/nadir/forward triplet (20 m pixels, N x N): quick raster and matching trials")
    _common(p)
    p.add_argument("--size", type=int, default=480, help="image lines and columns, pixels (default 480)")
    p.add_argument("--gcps", type=int, default=8, help="control points (default 8)")
    p.add_argument("--checks", type=int, default=8, help="check points (default 8)")
    p.add_argument("--tie-points", type=int, default=30, help="tie points, each seen by all three images (default 30)")

    sim.set_defaults(func=run)


def _fail(message: str) -> int:
    """Print ``message`` as ``pba simulate``'s error; the exit status of a bad argument (2)."""
    print(f"pba simulate: {message}", file=sys.stderr)
    return 2


def _job_options(args: argparse.Namespace) -> dict:
    """options.ephemeris / options.attitude from --weight-ephemeris and --weight-attitude."""
    options: dict = {}
    if args.weight_ephemeris:
        try:
            pos, vel = (float(x) for x in args.weight_ephemeris.split(","))
        except ValueError:
            raise SystemExit(_fail("--weight-ephemeris needs two numbers: SIGMA_M,SIGMA_M_S (e.g. 10,0.05)")) from None
        options["ephemeris"] = {"sigma_position_m": pos, "sigma_velocity_m_s": vel}
    if args.weight_attitude is not None:
        options["attitude"] = {"sigma_deg": [args.weight_attitude] * 3}
    return options


def _rpc_settings(args: argparse.Namespace) -> RpcSettings | None:
    """RpcSettings from --rpc-model, --rpc-bias and --rpc-images (exit with a message when bad)."""
    if args.rpc_model is None:
        if args.rpc_bias or args.rpc_images:
            raise SystemExit(_fail("--rpc-bias and --rpc-images need --rpc-model (RPC-SHIFT, RPC-DRIFT or RPC-AFFINE)"))
        return None
    try:
        bias = parse_bias(args.rpc_bias)
        images = tuple(int(x) for x in args.rpc_images.split(",")) if args.rpc_images else None
    except ValueError as exc:
        raise SystemExit(_fail(f"--rpc-bias / --rpc-images: {exc}")) from None
    return RpcSettings(args.rpc_model, bias, images)


def _iop_errors(value: str):
    if value in ("none", "default"):
        return value
    return json.loads(Path(value).read_text())


def _scene(args: argparse.Namespace, settings: SceneSettings):
    """The simulated scene of the preset ``args.preset``."""
    if args.preset == "prism-single":
        return presets.prism_single(settings, args.camera, args.gcps, args.checks, args.chip_layout)
    if args.preset == "prism-triplet":
        return presets.prism_triplet(settings, args.gcps, args.checks, args.tie_points, args.chip_layout)
    if args.preset == "cbers-scene":
        return presets.cbers_scene(settings, args.gcps, args.checks)
    if args.preset == "cbers-lines":
        return cbers_lines(
            settings, args.lines, args.gcps, args.checks, args.yaw_steering, args.line_noise_px, args.check_lines
        )
    if args.preset == "small-triplet":
        return presets.small_triplet(settings, args.size, args.gcps, args.checks, args.tie_points)
    return presets.strip(settings, args.triplets, args.tie_points, args.gcps, args.checks)


def run(args: argparse.Namespace) -> int:
    settings = SceneSettings(
        preset=args.preset,
        seed=args.seed,
        name=args.name or f"simulated {args.preset} (seed {args.seed})",
        model=args.model,
        noise_px=args.noise_px,
        gcp_sigma_m=args.gcp_sigma_m,
        truth_step_lines=args.truth_step,
        jitter_rad=args.jitter_rad,
        iop_errors=_iop_errors(args.iop_errors),
        attitude_sigma_deg=args.attitude_noise_deg,
        job_options=_job_options(args),
        rpc=_rpc_settings(args),
    )
    if args.preset == "small-triplet" and args.size < presets.SMALL_MIN_PX:
        return _fail(f"small-triplet --size {args.size}: at least {presets.SMALL_MIN_PX} pixels")
    t0 = time.perf_counter()
    try:
        scene = _scene(args, settings)
    except RpcSettingsError as exc:
        raise SystemExit(_fail(str(exc))) from None
    job_path, truth_path = write_documents(scene, Path(args.output), args.truth, args.indent)
    if args.raster:
        from solver.simulate.raster import write_rasters

        for path in write_rasters(scene, job_path, texture=args.raster_texture, seed=args.seed):
            print(f"{path}: synthetic raster")
    n_obs = len(scene.noisy_observations())
    print(
        f"{job_path}: {len(scene.images)} images, {len(scene.points)} points, {n_obs} observations "
        f"({time.perf_counter() - t0:.1f} s); truth in {truth_path}"
    )
    return 0

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

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from solver.blocks.kind import BlockDefaults
from solver.errors import Problem
from solver.platforms import get_model

if TYPE_CHECKING:  # pragma: no cover
    from solver.schema.job import Job
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


class ImageKind(BlockDefaults):
    """The images' platform parameters: one block per image or per shared attitude. Its values
    are initialised and reported with the images (:mod:`solver.engine.initialize`, the report's
    ``images`` section: they are the core); this kind builds, shares, counts and names them."""

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

    def names(self, problem: "AdjustmentState") -> list[str]:
        out = []
        for block in self.blocks(problem):
            img = problem.images[block.images[0]]  # a shared block is named after its first image
            out += [f"{img.id}/{p.name}" for p in img.model.parameters(img.options)]
        return out


KIND = ImageKind()

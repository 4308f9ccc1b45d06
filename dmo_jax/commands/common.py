"""The options the method's commands share (preset, recipe, ``--set``, ``--coarse``, ``--sweep``),
and the one-line failure and JSON output of every command (``envs.commands.common``)."""
from __future__ import annotations

from envs.commands.common import fail, write_json

__all__ = ["fail", "write_json", "add_preset_argument", "add_recipe_argument", "add_set_argument", "parse_coarse",
           "parse_sweep"]


def add_preset_argument(parser) -> None:
    from dmo_jax.config import DEFAULT_PRESET, PRESETS

    parser.add_argument("--preset", default=DEFAULT_PRESET, choices=tuple(PRESETS),
                        help=f"network sizes and training settings (default {DEFAULT_PRESET}): tiny for tests, cpu "
                        "for a 2-core CPU at 96 px, paper = the paper's at 256 px")


def add_set_argument(parser, purpose: str) -> None:
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE",
                        help=f"{purpose}: a training setting (train.FIELD, any dmo_jax.config.TrainConfig field, "
                        "e.g. train.dmo_steps=2400), how the head reads depth (head.depth_cue=true, "
                        "head.depth_cue_range=0.1) or the image size (preset.image_size=64, a multiple of 32 for "
                        "cpu and paper; data then defaults to data/<size>px); the section may be left out; "
                        "repeatable")


def add_recipe_argument(parser, purpose: str = "what the networks train on") -> None:
    from dmo_jax.config import RECIPES

    parser.add_argument("--recipe", choices=RECIPES,
                        help=f"training recipe: {purpose}. paper: the paper's negatives and DMO inputs; bank: "
                        "about half of the EBM's in-data negatives are each scene's nearest training motions, and "
                        "its target ranks every candidate by its distance from the scene's motion (default: the "
                        "preset's own, dmo_jax.config.RECIPES)")


def parse_coarse(text: str | None):
    """``"6,64"`` -> ``CoarseRanking(stride=6, keep=64)``; ``"full"`` -> None; None -> ``"preset"``."""
    from dmo_jax.config import CoarseRanking

    if text is None:
        return "preset"
    if text == "full":
        return None
    try:
        stride, keep = (int(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--coarse must be STRIDE,KEEP (e.g. 6,64) or full, got {text!r}") from None
    if stride < 1 or keep < 1:
        raise ValueError(f"--coarse {text}: STRIDE and KEEP must be positive")
    return CoarseRanking(stride, keep)


def parse_sweep(text: str | None) -> tuple[str, list[int]] | None:
    """``"n=1,8,1000"`` -> ``("n", [1, 8, 1000])``; ``"R=1,5,10"`` -> ``("R", [1, 5, 10])``."""
    if text is None:
        return None
    name, _, values = text.partition("=")
    try:
        numbers = [int(v) for v in values.split(",") if v.strip()]
    except ValueError:
        numbers = []
    if name not in ("n", "R") or not numbers:
        raise ValueError(f"--sweep must look like n=1,8,1000 or R=1,5,10, got {text!r}")
    return name, numbers

"""Argument types and the parent parsers that the subcommands share."""

from __future__ import annotations

import argparse
from pathlib import Path

from optitact.errors import InputError


def int_at_least(minimum: int, what: str):
    """An argparse type: an integer >= ``minimum``."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if v < minimum:
            raise argparse.ArgumentTypeError(f"expected {what}, got {v}")
        return v

    return parse


positive_int = int_at_least(1, "a positive integer")
seed_int = int_at_least(0, "a non-negative integer")


def size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> ``(640, 480)``; InputError otherwise (a one-line CLI error)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size must look like 640x480 (WIDTHxHEIGHT), got {text!r}") from None
    return w, h


def _parent() -> argparse.ArgumentParser:
    return argparse.ArgumentParser(add_help=False)


def seed_parent(what: str = "seed") -> argparse.ArgumentParser:
    """``--seed`` (default 0)."""
    p = _parent()
    p.add_argument("--seed", type=seed_int, default=0, help=f"{what} (default 0)")
    return p


def variant_parent() -> argparse.ArgumentParser:
    """``--variant``: the Mitsuba variant."""
    p = _parent()
    p.add_argument("--variant", default=None,
                   help="Mitsuba variant (default: fastest that works: cuda_ad_rgb > llvm_ad_rgb > scalar_rgb)")
    return p


def image_size_parent() -> argparse.ArgumentParser:
    """``--width`` and ``--height`` of the camera image."""
    p = _parent()
    p.add_argument("--width", type=positive_int, default=640, help="image width (default 640)")
    p.add_argument("--height", type=positive_int, default=480, help="image height (default 480)")
    return p


def spp_parent(default: int = 64, what: str = "samples per pixel") -> argparse.ArgumentParser:
    """``--spp``."""
    p = _parent()
    p.add_argument("--spp", type=positive_int, default=default, help=f"{what} (default {default})")
    return p


def render_parents(*, spp: int = 64) -> list[argparse.ArgumentParser]:
    """What rendering a frame takes: spp, seed, ADC bits, variant and image size."""
    bits = _parent()
    bits.add_argument("--bits", type=int, choices=(8, 10, 12, 16), default=8,
                      help="ADC bit depth of the frame (default 8; >8 bits write 16-bit PNG)")
    return [spp_parent(spp), seed_parent("seed of the render and the camera noise"), bits, variant_parent(),
            image_size_parent()]


def plot_parent(help: str) -> argparse.ArgumentParser:
    """``--plot PLOT.png``."""
    p = _parent()
    p.add_argument("--plot", type=Path, default=None, metavar="PLOT.png", help=help)
    return p


def render_mode_choices() -> tuple[str, ...]:
    """How calibration frames can be rendered."""
    return ("two_stage", "pixels", "full")

"""Repeat scans of the unloaded block (a model-free noise floor) and of the loaded block.

A lab measures its own noise by scanning the unloaded block again, ``r`` more times, without
touching anything: the block does not move between the scans and the scanner stands where it
stood, so any difference between two of these scans is measurement noise. The virtual lab does
the same on the unloaded ray-cast geometry of each test (:class:`ScanGeometry`, scanner frame,
metres): every repeat is one more call of ``ScanNoise.apply`` (its own per-point noise,
dropouts, outliers and its own rigid drift), exactly as a test's own scans are drawn.

Seeds: the repeats of test ``index`` of ``group`` draw from
``SeedSequence(seed, spawn_key=(group key, index, 1))`` (:func:`repeat_rng`), a stream separate
from the test's own (:func:`vtestbed.world.physics.test_rng`, spawn key ``(group key, index)``),
so taking repeats changes no number of the test itself, and repeat ``k`` is the same whatever
the number of repeats asked for (the stream is consumed in order). A lab may also scan the
loaded block again, wire still tensioned (``[scanner] loaded_repeats``): those draw from
:func:`loaded_repeat_rng`, spawn key ``(group key, index, 2)``, on the loaded geometry, so that
the researcher can average both ends of a displacement (:mod:`vtestbed.researcher.scan_mean`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..transforms import homogeneous, invert, matrix_from_rotation_vector
from .physics import GROUP_KEYS
from .scan_noise import ScanGeometry, ScanNoise

__all__ = [
    "LOADED_REPEAT_STREAM",
    "REPEAT_STREAM",
    "draw_repeat_scans",
    "loaded_repeat_geometries",
    "loaded_repeat_rng",
    "repeat_rng",
]

REPEAT_STREAM = 1  # last spawn-key entry of the repeat scans' stream
LOADED_REPEAT_STREAM = 2  # last spawn-key entry of the loaded block's repeat scans


def repeat_rng(seed: int, group: str, index: int) -> np.random.Generator:
    """The generator of the repeat scans of test ``index`` of ``group`` under scenario seed ``seed``.

    Parameters
    ----------
    seed : int
        The scenario's seed.
    group : str
        ``"identification"`` or ``"validation"``.
    index : int
        The test's index in its group (0-based).

    Returns
    -------
    numpy.random.Generator
        Independent of :func:`vtestbed.world.physics.test_rng` for every seed, group and index.
    """
    key = (GROUP_KEYS[group], index, REPEAT_STREAM)
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


def loaded_repeat_rng(seed: int, group: str, index: int) -> np.random.Generator:
    """The generator of the loaded block's repeat scans of test ``index`` of ``group``: as
    :func:`repeat_rng`, independent of it and of the test's own stream."""
    key = (GROUP_KEYS[group], index, LOADED_REPEAT_STREAM)
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


def loaded_repeat_geometries(
    hits_loaded: ScanGeometry,
    block_in_scanner: np.ndarray,
    displacement: np.ndarray,
    effects: tuple,
    repeats: int,
) -> list[ScanGeometry] | None:
    """The loaded block's noise-free hits at each loaded repeat 1..``repeats``, moved on by the
    effects that move a loaded block (load creep, ``WorldEffect.loaded_motion``); None when none does.

    Parameters
    ----------
    hits_loaded : ScanGeometry
        The loaded scan's hits (scanner frame, m).
    block_in_scanner : (4, 4) array
        The loaded block's true pose in the scanner frame.
    displacement : (6,) array
        The test's elastic block displacement, unloaded to loaded [m, rad], block frame.
    effects : tuple of WorldEffect
        The world's hidden effects.
    repeats : int
        Loaded repeats per test.

    The hit points move rigidly with the block; the rays, the normals and so the incidence the
    noise model reads stay (the campaign trial keeps only the incidence, and must draw the same
    scans): for motions of a few um and urad that is the block's surface sampled a hair's breadth
    along it, with the noise of an incidence a few urad off, which no plane fit can tell.
    """
    movers = [e for e in effects if e.moves_loaded_block and not e.is_null]
    if not movers:
        return None
    out = []
    for k in range(1, repeats + 1):
        twist = sum(e.loaded_motion(displacement, k) for e in movers)
        moved = block_in_scanner @ homogeneous(matrix_from_rotation_vector(twist[3:]), twist[:3])
        motion = moved @ invert(block_in_scanner)  # scanner frame
        rot, shift = motion[:3, :3], motion[:3, 3]
        out.append(dataclasses.replace(hits_loaded, points_m=hits_loaded.points_m @ rot.T + shift))
    return out


def draw_repeat_scans(
    hits_unloaded: ScanGeometry,
    noise: ScanNoise | None,
    rng: np.random.Generator,
    repeats: int,
    effects: tuple = (),
    geometries: list[ScanGeometry] | None = None,
) -> list[np.ndarray]:
    """``repeats`` further noisy scans of one test's unloaded block, same scanner pose (or of its
    loaded block: ``hits_unloaded`` the loaded hits, ``rng`` :func:`loaded_repeat_rng`).

    Parameters
    ----------
    hits_unloaded : ScanGeometry
        The noise-free ray-cast hits of the unloaded block (scanner frame, m).
    noise : ScanNoise or None
        The scanner's errors; None is a perfect scanner, whose repeats are copies of the hits.
    rng : numpy.random.Generator
        The repeat stream (:func:`repeat_rng`), consumed in order: one ``noise.apply`` per scan,
        each with its own drift draw.
    repeats : int
        Number of repeat scans (0 gives an empty list).
    effects : tuple of WorldEffect
        The world's hidden effects: those that change the measurement chain (e.g. a scanner
        scale error) act on every repeat as on the test's own scans (they draw nothing).
    geometries : list of ScanGeometry, optional
        Per repeat, the hits to draw it from instead of ``hits_unloaded``: a loaded block that
        moves on between its scans (:func:`loaded_repeat_geometries`).

    Returns
    -------
    list of (M_k, 3) arrays
        The repeat clouds [m] in the scanner frame, as a scan file stores them.
    """
    chain = tuple(e for e in effects if e.changes_measurement and not e.is_null)
    scans = []
    for k in range(repeats):
        hits = hits_unloaded if geometries is None else geometries[k]
        points = noise.apply(hits, rng) if noise is not None else hits.points_m.copy()
        for effect in chain:
            points = effect.scan_points(points)
        scans.append(points)
    return scans

"""How big is an effect? Its share of the block's deflection over a scenario's tests.

For each test: the true block displacement under the wire load (unloaded to loaded, in the
unloaded block frame) in the clean world and in the world with the effect; the share is
``|d_effect - d_clean| / |d_clean|``, separately for translation and rotation, and for the
wrench the sensor reports. Equilibria only (no scans), so it takes a second or so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...transforms import displacement_in_block_frame
from ..rig import Rig
from ..truth import load_truth


@dataclass(frozen=True)
class EffectSize:
    """Shares [-] over a scenario's identification tests (RMS and largest)."""

    name: str
    translation_rms: float
    translation_max: float
    rotation_rms: float
    rotation_max: float
    wrench_rms: float

    def to_dict(self) -> dict:
        return self.__dict__.copy()


def _tests(scenario, rig: Rig):
    out = []
    load = scenario.load
    for i, q in enumerate(scenario.poses):
        rig.command(q)
        rig.hook(load.hooks[i], load.anchors[i])
        s0 = rig.solve()
        s1 = rig.tighten(load.tensions[i])
        d = displacement_in_block_frame(s0.block_pose, s1.block_pose)
        w = s1.sensor_wrench - s0.sensor_wrench
        for effect in rig.effects:
            if effect.changes_measurement:
                w = effect.wrench_reading(s1.sensor_wrench, "loaded") - effect.wrench_reading(
                    s0.sensor_wrench, "unloaded"
                )
                d = np.concatenate([effect.scan_points(d[None, :3])[0], d[3:]])
        out.append((d, w))
    return out


def effect_sizes(scenario, effects) -> list[EffectSize]:
    """Each effect's share of the block's deflection (and of the wrench change) on ``scenario``'s tests."""
    truth = load_truth(scenario.robot_name)
    clean = _tests(scenario, Rig(scenario.robot, scenario.lab, truth=truth))
    sizes = []
    for effect in effects:
        hidden = _tests(scenario, Rig(scenario.robot, scenario.lab, truth=truth, effects=(effect,)))
        t, r, w = [], [], []
        for (d0, w0), (d1, w1) in zip(clean, hidden):
            t.append(np.linalg.norm(d1[:3] - d0[:3]) / np.linalg.norm(d0[:3]))
            r.append(np.linalg.norm(d1[3:] - d0[3:]) / np.linalg.norm(d0[3:]))
            w.append(np.linalg.norm(w1 - w0) / np.linalg.norm(w0))
        t, r, w = np.array(t), np.array(r), np.array(w)
        sizes.append(EffectSize(effect.name, float(np.sqrt(np.mean(t**2))), float(t.max()),
                                float(np.sqrt(np.mean(r**2))), float(r.max()), float(np.sqrt(np.mean(w**2)))))  # fmt: skip
    return sizes

"""Hidden physics: named effects the paper's model leaves out, for the truth world only.

A scenario hides effects in its world with ``[[world.effects]]`` tables (``name`` plus
parameters); :func:`parse_effects` validates them; the rig, the scene builder and the measurement
chain apply them; ``truth.json`` records them; nothing in the dataset files reveals them.
``vtestbed effects`` lists the names, parameters, units and realistic defaults
(docs/effects.md derives each).
"""

from __future__ import annotations

from ...schema import Fields
from .base import ExtraHinge, Param, WorldEffect, check_effects
from .creep import LoadCreep
from .joints import JointCoupling, NonlinearJoint
from .measurement import FtBiasDrift, FtMisalignment, ScannerScale
from .mounting import BlockOffset, GeometricError
from .structure import BaseCompliance, GravityCompensator, LinkCompliance

EFFECT_TYPES: tuple[type[WorldEffect], ...] = (
    LinkCompliance,
    JointCoupling,
    NonlinearJoint,
    GravityCompensator,
    BaseCompliance,
    FtMisalignment,
    FtBiasDrift,
    GeometricError,
    BlockOffset,
    ScannerScale,
    LoadCreep,
)
EFFECTS = {t.name: t for t in EFFECT_TYPES}

__all__ = [
    "EFFECTS",
    "BaseCompliance",
    "BlockOffset",
    "ExtraHinge",
    "FtBiasDrift",
    "FtMisalignment",
    "GeometricError",
    "GravityCompensator",
    "JointCoupling",
    "LinkCompliance",
    "LoadCreep",
    "NonlinearJoint",
    "Param",
    "ScannerScale",
    "WorldEffect",
    "check_effects",
    "parse_effect",
    "parse_effects",
]


def _value(param: Param, value, f: Fields, where: str):
    if param.kind == "integer":
        return f.integer(value, where, int(param.low), int(param.high))
    if param.kind == "pair":
        if not isinstance(value, list) or len(value) != 2:
            raise f.error(
                where,
                f"must be two joint numbers [i, j] in {int(param.low)}..{int(param.high)}, got {value!r}",
            )
        pair = tuple(
            f.integer(v, f"{where}[{i}]", int(param.low), int(param.high)) for i, v in enumerate(value)
        )
        if pair[0] == pair[1]:
            raise f.error(where, f"must be two different joints, got {list(pair)}")
        return pair
    if param.kind == "vector":
        if not isinstance(value, list) or len(value) != param.length:
            raise f.error(where, f"must be a list of {param.length} numbers [{param.unit}], got {value!r}")
        return tuple(f.number(v, f"{where}[{i}]", param.low, param.high) for i, v in enumerate(value))
    return f.number(value, where, param.low, param.high)  # inf only where the range allows it (rigid)


def parse_effect(table, f: Fields, where: str) -> WorldEffect:
    """One ``[[world.effects]]`` table -> an effect; errors name the field and the valid values."""
    f.table(table, where)
    if "name" not in table:
        raise f.error(f"{where}.name", f"is required; valid names: {', '.join(EFFECTS)}")
    kind = EFFECTS[f.choice(table["name"], f"{where}.name", tuple(EFFECTS))]
    params = {p.name: p for p in kind.PARAMS}
    f.table(table, where, ("name", *params))
    values = {
        name: _value(p, table[name], f, f"{where}.{name}") for name, p in params.items() if name in table
    }
    return kind(**values)


TARGET_KINDS = ("integer", "pair")  # the parameters that say where an effect acts: a link, a joint, a pair
TARGET_WORDS = {"joints": "joint pair"}


def effect_identity(effect: WorldEffect) -> tuple[str, tuple]:
    """What an effect is and where it acts: its name and its target parameters (``link``,
    ``joint``, ``joints`` as an unordered pair; defaults filled in). Effects without a target
    (the sensor's, the scanner's, the base's) act on the one thing there is: the name alone."""
    target = tuple(
        (p.name, tuple(sorted(value)) if p.kind == "pair" else value)
        for p in effect.PARAMS
        if p.kind in TARGET_KINDS
        for value in (getattr(effect, p.name),)
    )
    return effect.name, target


def _describe(identity: tuple[str, tuple]) -> str:
    name, target = identity
    where = ", ".join(f"{k} = {list(v) if isinstance(v, tuple) else v}" for k, v in target)
    return f"{name} on {where}" if where else name


def parse_effects(value, f: Fields, where: str = "world.effects") -> tuple[WorldEffect, ...]:
    """The effects of a ``[[world.effects]]`` array of tables (an empty tuple when absent).

    One rule for repeats: an effect may be listed once per target (the same name on the same
    link, joint or joint pair twice is refused). Two entries would either collide in the MuJoCo
    model (two hinges of one name) or silently add up, and neither is what a reader of the file
    expects; one entry with the combined size says it plainly.
    """
    if not isinstance(value, list) or not all(isinstance(t, dict) for t in value):
        raise f.error(
            where, "must be an array of tables ([[world.effects]], each with a name and parameters)"
        )
    effects = tuple(parse_effect(t, f, f"{where}[{i}]") for i, t in enumerate(value))
    seen: dict[tuple, int] = {}
    for i, effect in enumerate(effects):
        identity = effect_identity(effect)
        if identity in seen:
            target = " and ".join(TARGET_WORDS.get(name, name) for name, _ in identity[1])
            rule = f"listed once per {target}" if target else "listed once (it has no target)"
            raise f.error(
                f"{where}[{i}]",
                f"repeats {where}[{seen[identity]}] ({_describe(identity)}): an effect may be {rule};"
                " give one entry with the combined size" + (f", or another {target}" if target else ""),
            )
        seen[identity] = i
    return effects

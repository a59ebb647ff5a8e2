"""``vtestbed effects [size SCENARIO]``: the hidden effects the truth world can hold, and their size."""

from __future__ import annotations

from pathlib import Path

from ..files import dumps


def _fmt(value) -> str:
    return "[" + ", ".join(f"{v:g}" for v in value) + "]" if isinstance(value, tuple) else f"{value:g}"


def _cmd_list(args) -> int:
    from ..world.effects import EFFECTS

    if args.json:
        data = {
            name: {"summary": t.summary, "params": [p.__dict__ for p in t.PARAMS]}
            for name, t in EFFECTS.items()
        }
        print(dumps(data, indent=1, default=str))
        return 0
    for name, kind in EFFECTS.items():
        print(f"{name}: {kind.summary}")
        for p in kind.PARAMS:
            print(
                f"    {p.name} [{p.unit}] default {_fmt(p.default)}, range [{p.low:g}, {p.high:g}]: {p.doc}"
            )
    print(
        'in a scenario: [[world.effects]] with name = "..." and the parameters (defaults are realistic sizes)'
    )
    return 0


def _cmd_size(args) -> int:
    from ..scenario import load_scenario
    from ..world.effects import EFFECTS
    from ..world.effects.size import effect_sizes

    scenario = load_scenario(args.scenario)
    effects = scenario.effects or tuple(kind() for kind in EFFECTS.values())
    sizes = effect_sizes(scenario, effects)
    if args.json:
        print(dumps([s.to_dict() for s in sizes], indent=1))
        return 0
    which = "the scenario's effects" if scenario.effects else "every effect at its realistic default"
    print(f"{scenario.name}: {scenario.n_tests} tests, {which}; share of the clean block deflection [%]")
    print(f"{'effect':22}{'transl. RMS':>12}{'max':>8}{'rot. RMS':>10}{'max':>8}{'wrench RMS':>12}")
    for s in sizes:
        print(f"{s.name:22}{s.translation_rms * 100:12.2f}{s.translation_max * 100:8.2f}{s.rotation_rms * 100:10.2f}"
              f"{s.rotation_max * 100:8.2f}{s.wrench_rms * 100:12.2f}")  # fmt: skip
    return 0


def register(sub) -> None:
    p = sub.add_parser("effects", help="hidden world effects: names, parameters, realistic sizes")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=_cmd_list)
    inner = p.add_subparsers(dest="effects_command")
    s = inner.add_parser("size", help="each effect's share of the block deflection on a scenario's tests")
    s.add_argument("scenario", type=Path)
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=_cmd_size)

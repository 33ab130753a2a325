"""Run one estimator (or the controller) as a CAN node.

Run one estimator, or the controller of a closed-loop scenario (NAME 'controller'), as a node on a
co-simulation's bus. 'cosim run' starts its nodes this way (with --spec). Without --spec the node
joins the running co-simulation, whose scenario marks it 'external = true' (to run it by hand, e.g.
in a debugger).
"""

from __future__ import annotations

import argparse
import sys

from cosim.errors import CosimError


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("estimator", metavar="NAME", help="the estimator's name in the scenario, or 'controller'")
    p.add_argument("--spec", metavar="FILE.json", help="the node spec written by 'cosim run'")
    p.add_argument("--run", metavar="ID", help="which running co-simulation (default: the only one)")


def main(args: argparse.Namespace) -> int:
    # A node never reads or writes MF4 files, but python-can's first import loads its MF4 support,
    # asammdf with pandas, where the export extra is installed: a second of every node's start-up.
    # Kept out of that import, python-can leaves MF4 out (as where asammdf is not installed);
    # asammdf itself stays importable afterwards (cosim's MF4 export uses it directly).
    hidden = "asammdf" not in sys.modules and "can" not in sys.modules
    if hidden:
        sys.modules["asammdf"] = None  # type: ignore[assignment]
    try:
        from cosim.run.node import load_spec, serve
    finally:
        if hidden and sys.modules.get("asammdf", False) is None:
            del sys.modules["asammdf"]

    if args.spec:
        spec = load_spec(args.spec)
        if spec.name != args.estimator:
            raise CosimError(f"{args.spec} is the spec of node {spec.name!r}, not {args.estimator!r}")
    else:
        from cosim.bus.monitor import find_run
        from cosim.run.node import NodeSpec

        info = find_run(args.run, f"cosim node {args.estimator}")
        if args.estimator not in info.get("nodes", {}):
            raise CosimError(
                f"the running co-simulation ({info['scenario']}) expects no external node {args.estimator!r}; "
                f"mark it 'external = true' in the scenario's [[estimators]] (or [controller]) to start it by hand"
            )
        spec = NodeSpec.from_json(info["nodes"][args.estimator])
    return serve(spec)

"""Run one estimator (or the controller) as a CAN node.

Run one estimator, or the controller of a closed-loop scenario (NAME 'controller'), as a node on a
co-simulation's bus. 'cosim run' starts its nodes this way (with --spec). Without --spec the node
joins the running co-simulation, whose scenario marks it 'external = true' (to run it by hand, e.g.
in a debugger).
"""

from __future__ import annotations

import argparse

from cosim.errors import CosimError


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("estimator", metavar="NAME", help="the estimator's name in the scenario, or 'controller'")
    p.add_argument("--spec", metavar="FILE.json", help="the node spec written by 'cosim run'")
    p.add_argument("--run", metavar="ID", help="which running co-simulation (default: the only one)")


def main(args: argparse.Namespace) -> int:
    from cosim.run.node import load_spec, serve  # python-can without its MF4 support: cosim.cli.main

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

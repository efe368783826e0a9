"""The `yowo` command line. Each verb is a function taking the parsed arguments
and returning the process exit code; heavy imports happen inside the verb."""
from __future__ import annotations

import argparse
import sys

from yowo_common.ros.bag import BagError


def cmd_info(args) -> int:
    """Summarise a recording: topics, types, counts, and the CMCs found."""
    from rich.console import Console
    from rich.table import Table

    from .contract import discover_inputs

    console = Console()
    inputs = discover_inputs(args.bag)
    table = Table(title=str(args.bag))
    for col in ("topic", "type", "messages"):
        table.add_column(col)
    for t in inputs.topics:
        table.add_row(t.name, t.msgtype, str(t.count))
    console.print(table)
    console.print(f"ego camera: {'yes' if inputs.has_ego else 'no'}; "
                  f"CMCs ({len(inputs.cmc_names)}): {', '.join(inputs.cmc_names) or '-'}; "
                  f"ground truth: {'yes' if inputs.has_ground_truth else 'no'}")
    for problem in inputs.problems:
        console.print(f"[yellow]warning:[/] {problem}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="yowo", description="YOWO: map a scene and register its ceiling cameras from one walk.")
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="VERB")

    p = verbs.add_parser("info", help="list a recording's topics and the cameras YOWO finds in it")
    p.add_argument("bag", help="rosbag2 directory or .mcap file")
    p.set_defaults(func=cmd_info)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except BagError as exc:
        print(f"yowo {args.verb}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())

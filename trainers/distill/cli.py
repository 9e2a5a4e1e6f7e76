"""``python -m trainers.distill``: a preset, its overrides, the run's folder."""

from __future__ import annotations

import argparse

from torchpark.files import directory_arg, locked
from trainers.config import field_lines
from trainers.distill.config import PRESETS, load_distill_config
from trainers.distill.loop import OUTPUTS, distill

USAGE = """python -m trainers.distill --preset policy_alone --out DIR [--resume | --overwrite]
                                 [key=value ...]"""


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m trainers.distill", usage=USAGE,
        description="DAgger from the hand-written teacher to a policy alone "
                    "(trainers.distill). Its config's fields, overridden as key=value "
                    "(dot notation), with the policy_alone preset's values:",
        epilog=field_lines(PRESETS["policy_alone"]()),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", default="policy_alone", help=", ".join(PRESETS))
    parser.add_argument("--out", required=True, type=directory_arg,
                        help="directory of the student's files")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the outputs already in --out (refused by default)")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run in --out from its last finished iteration, "
                             "exactly (the same config; dagger.iterations may be raised)")
    parser.add_argument("overrides", nargs="*", help="config fields as key=value")
    args = parser.parse_intermixed_args(argv)
    out = args.out
    try:
        cfg = load_distill_config(args.preset, args.overrides)
        if args.resume and args.overwrite:
            raise ValueError("--resume continues the run in --out, --overwrite replaces it: "
                             "pass one of them")
        with locked(out, "--out"):
            existing = [name for name in OUTPUTS if (out / name).exists()]
            if existing and not (args.overwrite or args.resume):
                raise ValueError(f"{out / existing[0]} exists ({len(existing)} of the outputs "
                                 f"do): pass another --out, or --overwrite to replace them")
            print(distill(cfg, out, resume=args.resume))
    except (ValueError, OSError) as err:
        parser.exit(2, f"{parser.prog}: error: {str(err).splitlines()[0]}\n")

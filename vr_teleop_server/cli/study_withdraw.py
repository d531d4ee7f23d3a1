"""`vr-teleop study withdraw DIR P07`: delete a participant's data from a study folder, keeping only the fact and
time of the withdrawal in its event log. Run it with the server that hosts the study stopped (the folder is
locked while it is open)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..study.folder import FolderError, Refused, withdraw


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("withdraw", help="delete a participant's data from a study folder (keeps the fact)",
                       description="Delete a participant's data: their recordings and answers, and their events "
                                   "in the log; the log keeps only that they withdrew, and when.")
    p.add_argument("dir", type=Path, metavar="DIR", help="the study folder")
    p.add_argument("participant", metavar="PID", help="the participant's pseudonym, e.g. P07")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        withdraw(args.dir, args.participant)
    except (FolderError, Refused) as exc:
        print(f"vr-teleop study withdraw: error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.participant} withdrawn from {args.dir}: their data is deleted; the log keeps the withdrawal "
          "and its time")
    return 0

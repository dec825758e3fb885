"""``windbench-report DIR...`` (placeholder until the report issue lands)."""

import sys


def main() -> None:
    print("windbench-report: the report is not built yet", file=sys.stderr)
    sys.exit(1)

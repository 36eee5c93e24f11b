"""Check a commit message: a subject of at most MAX_SUBJECT characters, then a blank line before the body.

    python tools/check_commit_message.py .git/COMMIT_EDITMSG     # one message (as a commit-msg hook)
    python tools/check_commit_message.py --range main..HEAD      # every commit of a branch

Install as a hook: ``ln -s ../../tools/check_commit_message.py .git/hooks/commit-msg`` (CONTRIBUTING.md).
"""

from __future__ import annotations

import argparse
import subprocess
import sys

MAX_SUBJECT = 72


def problems(message: str) -> list[str]:
    """What is wrong with ``message`` (comment lines of git's template ignored); empty when it is fine."""
    lines = [ln for ln in message.splitlines() if not ln.startswith("#")]
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines or not lines[0].strip():
        return ["empty subject"]
    out = []
    if len(lines[0]) > MAX_SUBJECT:
        out.append(f"subject has {len(lines[0])} characters (at most {MAX_SUBJECT})")
    if len(lines) > 1 and lines[1].strip():
        out.append("no blank line between the subject and the body")
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("file", nargs="?")
    p.add_argument("--range", help="a git revision range, e.g. main..HEAD")
    args = p.parse_args(argv)
    if args.range:
        out = subprocess.run(["git", "log", "--format=%H%x00%B%x01", args.range], capture_output=True, text=True,
                             check=True).stdout
        messages = [m.strip("\n").split("\x00", 1) for m in out.split("\x01") if m.strip()]
    elif args.file:
        with open(args.file, encoding="utf-8") as fh:
            messages = [("message", fh.read())]
    else:
        p.error("give a message file or --range")
    bad = 0
    for name, message in messages:
        for problem in problems(message):
            print(f"{name[:12]}: {problem}", file=sys.stderr)
            bad += 1
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())

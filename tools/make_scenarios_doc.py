"""Write docs/scenarios.md, the reference of every scenario key, from the declarations in the code.

    python tools/make_scenarios_doc.py [--check]

Run it after adding or changing a key, a controller kind, a reference kind or a plant backend; the
test suite fails while the committed document is stale. With --check it writes nothing and exits 1
when the document differs from what it would write.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from qcontrol.scenario.document import scenarios_markdown  # noqa: E402

DOCUMENT = ROOT / "docs" / "scenarios.md"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if docs/scenarios.md is stale")
    args = parser.parse_args()
    text = scenarios_markdown()
    current = DOCUMENT.read_text(encoding="utf-8") if DOCUMENT.is_file() else ""
    if args.check:
        if current != text:
            print(f"{DOCUMENT.relative_to(ROOT)} is stale: run python tools/make_scenarios_doc.py")
            return 1
        print(f"{DOCUMENT.relative_to(ROOT)} is up to date")
        return 0
    DOCUMENT.write_text(text, encoding="utf-8")
    print(f"wrote {DOCUMENT.relative_to(ROOT)} ({len(text.splitlines())} lines)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

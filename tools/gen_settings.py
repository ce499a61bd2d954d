"""Write the files generated from the knob registry (slimseg/dynamic/knobs.py): the settings
table of docs/settings.md and export/cpp/include/slimseg/settings_generated.hpp.

    python tools/gen_settings.py        # from the repository root; review the diff like code
"""

from __future__ import annotations

import sys
from pathlib import Path

from slimseg.dynamic.knobs_render import rendered

if __name__ == "__main__":
    root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(".")
    for rel, text in rendered().items():
        path = root / rel
        if path.is_file() and path.read_text() == text:
            print(f"{rel}: up to date")
            continue
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(text)
        tmp.replace(path)
        print(f"{rel}: written")

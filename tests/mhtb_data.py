"""Where the tests find the real MHTB tests: read in place from ``../shared/data/mhtb``, never copied."""

from pathlib import Path

import pytest

MHTB = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mhtb"
needs_mhtb = pytest.mark.skipif(not all((MHTB / f"{n}.json").exists() for n in ("P263968K", "P263981D")),
                                reason=f"the shared MHTB data ({MHTB}) is not beside the project")

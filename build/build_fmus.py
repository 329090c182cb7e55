"""Build the FlexiblePendulum and PDLowPass FMUs into build/fmus/ (only those whose sources changed).

    python build/build_fmus.py [NAME ...] [--out DIR] [--force] [--references]

``--references`` also regenerates the reference results under tests/reference/ (do it on purpose,
after a deliberate change of the physics or of the FMUs' defaults). The logic lives in
:mod:`orchestration.export`, which ``flexpend build`` calls too.
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from orchestration.export import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())

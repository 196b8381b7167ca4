"""Entry point inside Blender:

    blender -b --factory-startup --python-exit-code 1 --python tests/blender/run.py -- [pytest args]

Exits with pytest's status so a failing test fails the Blender run.
"""

import os
import sys
from pathlib import Path

import pytest

os.environ["MD_TESTS_IN_BLENDER"] = "1"  # conftest: Blender itself exits cleanly
here = Path(__file__).resolve().parent
argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
code = pytest.main([str(here), "-p", "no:cacheprovider", *argv])
sys.exit(int(code))

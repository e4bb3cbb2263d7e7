"""``python -m fap_py.soak --child NAME ...``: a soak's slave process (fap_py.soak.harness)."""
import sys

from ..errors import FapError
from .harness import CHILD_FLAG, child_main

if __name__ == "__main__":
    if len(sys.argv) < 9 or sys.argv[1] != CHILD_FLAG:
        sys.exit(f"usage: python -m fap_py.soak {CHILD_FLAG} NAME PATH NODE BAUD SEED RATE UNTIL "
                 "(a slave process of `fap soak`)")
    try:
        sys.exit(child_main(sys.argv[2:]))
    except (FapError, ValueError) as exc:     # an unknown protocol, a bad number, a port gone
        sys.exit(f"python -m fap_py.soak: {exc}")

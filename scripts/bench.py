"""Speed benchmark: taxi MAXQ-Q, batched population vs plain Python (``make bench``).

A thin entry to ``benchmarks/bench_taxi.py``; options: ``python scripts/bench.py --help``.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # envs/, agents/, benchmarks/

from benchmarks.bench_taxi import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())

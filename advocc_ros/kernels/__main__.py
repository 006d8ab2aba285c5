"""``python -m advocc_ros.kernels``: build the kernels' library now (``make install`` does), so
that a first heatmap or attack does not; prints where it is."""

import sys
import time

from advocc_ros.kernels.loader import KernelBuildError, library, library_path


def main() -> int:
    t0 = time.perf_counter()
    try:
        library()
    except KernelBuildError as exc:
        print(f'advocc_ros: {exc}', file=sys.stderr)
        return 1
    print(f'advocc_ros: kernels ready in {time.perf_counter() - t0:.1f} s: {library_path()}',
          file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())

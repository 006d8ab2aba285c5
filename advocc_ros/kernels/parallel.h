/* Rows of a kernel over a few POSIX threads started for the call and joined before it returns:
 * nothing persists between calls, so a process may fork at any time (the heatmap's workers). */
#ifndef ADVOCC_PARALLEL_H
#define ADVOCC_PARALLEL_H

#include <stdint.h>

typedef void (*row_fn)(void *context, int64_t row);

/* fn(context, row) for every row in [0, n), on at most `threads` threads (the caller's one of
 * them), each taking the next `chunk` rows until none is left. Rows must be independent. */
void parallel_rows(int64_t n, int64_t threads, int64_t chunk, row_fn fn, void *context);

#endif

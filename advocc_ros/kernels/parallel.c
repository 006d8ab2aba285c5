/* parallel_rows (parallel.h). */
#include "parallel.h"

#include <pthread.h>

#define MAX_THREADS 256

typedef struct {
    int64_t n, chunk;
    int64_t next; /* the next row to take (atomic) */
    row_fn fn;
    void *context;
} job_t;

static void *run_rows(void *arg)
{
    job_t *job = arg;
    for (;;) {
        int64_t first = __atomic_fetch_add(&job->next, job->chunk, __ATOMIC_RELAXED);
        if (first >= job->n)
            return NULL;
        int64_t last = first + job->chunk < job->n ? first + job->chunk : job->n;
        for (int64_t row = first; row < last; ++row)
            job->fn(job->context, row);
    }
}

void parallel_rows(int64_t n, int64_t threads, int64_t chunk, row_fn fn, void *context)
{
    job_t job = {n, chunk < 1 ? 1 : chunk, 0, fn, context};
    int64_t chunks = (n + job.chunk - 1) / job.chunk;
    if (threads > chunks)
        threads = chunks;
    if (threads > MAX_THREADS)
        threads = MAX_THREADS;
    pthread_t helpers[MAX_THREADS];
    int64_t started = 0;
    for (int64_t i = 1; i < threads; ++i) {
        if (pthread_create(&helpers[started], NULL, run_rows, &job) != 0)
            break; /* fewer threads: the rows still all run */
        ++started;
    }
    run_rows(&job);
    for (int64_t i = 0; i < started; ++i)
        pthread_join(helpers[i], NULL);
}

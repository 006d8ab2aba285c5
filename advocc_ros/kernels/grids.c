/* Passes over voxel blocks (attack/coverage.py, region.py, configurations.py): box sums along
 * lines, min-plus convolutions for box distances, the corridor's candidates and a bool
 * matrix's CSR form. Arrays are C-ordered; lines run along the last axis. */
#include <math.h>
#include <stdint.h>

#include "parallel.h"

/* out[l, i] = src[l, i] + src[l, i - 1] + src[l, i + 1] + ... (+- k) over `lines` lines of n,
 * terms outside the line skipped, always added in this order. */
void advocc_line_sums(const double *src, int64_t lines, int64_t n, int64_t k, double *out)
{
    for (int64_t l = 0; l < lines; ++l) {
        const double *s = src + l * n;
        double *o = out + l * n;
        for (int64_t i = 0; i < n; ++i) {
            double acc = s[i];
            for (int64_t d = 1; d <= k; ++d) {
                if (i - d >= 0)
                    acc += s[i - d];
                if (i + d < n)
                    acc += s[i + d];
            }
            o[i] = acc;
        }
    }
}

/* out[l, i - start] = min_o src[l, i + o] + costs[|o|] for i in [start, stop), the offsets
 * |o| < m inside the line (costs never decrease); out is filled with inf first, and lines
 * without a finite value are skipped. */
void advocc_min_plus(const float *src, int64_t lines, int64_t n, const float *costs, int64_t m,
                     int64_t start, int64_t stop, float *out)
{
    int64_t width = stop - start;
    for (int64_t l = 0; l < lines; ++l) {
        const float *s = src + l * n;
        float *o = out + l * width;
        int empty = 1;
        for (int64_t i = 0; i < width; ++i)
            o[i] = INFINITY;
        for (int64_t i = 0; i < n; ++i)
            if (s[i] < INFINITY) {
                empty = 0;
                break;
            }
        if (empty)
            continue;
        for (int64_t i = start; i < stop; ++i) {
            float best = s[i];
            for (int64_t d = 1; d < m; ++d) {
                if (costs[d] >= best)
                    break; /* costs grow with |o|: no farther voxel can do better */
                if (i - d >= 0) {
                    float v = s[i - d] + costs[d];
                    if (v < best)
                        best = v;
                }
                if (i + d < n) {
                    float v = s[i + d] + costs[d];
                    if (v < best)
                        best = v;
                }
            }
            o[i - start] = best;
        }
    }
}

/* cand[v] for the voxels v of weights[lo:hi] (shape n) with positive mass whose centre is within
 * `radius` of the segment a-b; returns how many had positive mass. */
int64_t advocc_corridor_candidates(const double *weights, const int64_t *shape,
                                   const int64_t *lo, const int64_t *hi, const double *origin,
                                   double voxel, const double *a, const double *b,
                                   double radius, uint8_t *cand)
{
    double ab[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    double inv = 1.0 / fmax(ab[0] * ab[0] + ab[1] * ab[1] + ab[2] * ab[2], 1e-12);
    int64_t positive = 0;
    for (int64_t i = lo[0]; i < hi[0]; ++i) {
        double px = origin[0] + ((double)i + 0.5) * voxel - a[0];
        for (int64_t j = lo[1]; j < hi[1]; ++j) {
            double py = origin[1] + ((double)j + 0.5) * voxel - a[1];
            for (int64_t k = lo[2]; k < hi[2]; ++k) {
                int64_t v = (i * shape[1] + j) * shape[2] + k;
                if (weights[v] <= 0.0)
                    continue;
                ++positive;
                double pz = origin[2] + ((double)k + 0.5) * voxel - a[2];
                double t = fmin(fmax((px * ab[0] + py * ab[1] + pz * ab[2]) * inv, 0.0), 1.0);
                double dx = px - t * ab[0], dy = py - t * ab[1], dz = pz - t * ab[2];
                cand[v] = dx * dx + dy * dy + dz * dz <= radius * radius;
            }
        }
    }
    return positive;
}

/* ---- a bool matrix in CSR form: counts per row, then the (sorted) column indices -------- */

typedef struct {
    const uint8_t *dense;
    int64_t m;
    int64_t *indptr; /* counts[i + 1] first, then the offsets */
    int64_t *indices;
} csr_t;

static void count_row(void *context, int64_t i)
{
    csr_t *c = context;
    const uint8_t *row = c->dense + i * c->m;
    int64_t count = 0;
    for (int64_t j = 0; j < c->m; ++j)
        count += row[j] != 0;
    c->indptr[i + 1] = count;
}

static void fill_row(void *context, int64_t i)
{
    csr_t *c = context;
    const uint8_t *row = c->dense + i * c->m;
    int64_t p = c->indptr[i];
    for (int64_t j = 0; j < c->m; ++j)
        if (row[j])
            c->indices[p++] = j;
}

/* indptr (n + 1) of the n x m bool matrix; returns the entries' count. */
int64_t advocc_csr_indptr(const uint8_t *dense, int64_t n, int64_t m, int64_t *indptr,
                          int64_t threads)
{
    csr_t c = {dense, m, indptr, 0};
    indptr[0] = 0;
    parallel_rows(n, threads, 64, count_row, &c);
    for (int64_t i = 0; i < n; ++i)
        indptr[i + 1] += indptr[i];
    return indptr[n];
}

/* The column indices of every row, at indptr's offsets. */
void advocc_csr_indices(const uint8_t *dense, int64_t n, int64_t m, const int64_t *indptr,
                        int64_t *indices, int64_t threads)
{
    csr_t c = {dense, m, (int64_t *)indptr, indices};
    parallel_rows(n, threads, 64, fill_row, &c);
}

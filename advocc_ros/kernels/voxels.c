/* The robot's links on a voxel grid (heatmap/build.py, attack/configurations.py): each link's
 * solid look-up table placed at T_base_link = (R, t) and tested at voxel centres, scanning only
 * the link's rotated bounding box and, in each column, the span where the table can be. */
#include <math.h>
#include <stdint.h>

#include "parallel.h"

typedef struct {
    const uint8_t *data;   /* all tables, flat */
    const int64_t *offset; /* (L,) each table's first cell */
    const int64_t *shape;  /* (L, 3) */
    const double *origin;  /* (L, 3) each table's corner in its link frame */
    double pitch;
    const double *box_lo, *box_hi; /* (L, 3) link bounding boxes in the link frames */
} tables_t;

/* floor/ceil results as indices, saturated far outside any grid (no undefined conversion). */
static int64_t to_index(double v)
{
    if (!(v > -4e18))
        return -(int64_t)4e18;
    if (v > 4e18)
        return (int64_t)4e18;
    return (int64_t)v;
}

static int64_t max64(int64_t a, int64_t b) { return a > b ? a : b; }
static int64_t min64(int64_t a, int64_t b) { return a < b ? a : b; }

/* Per axis, the index range [lo, hi] of the voxel centres origin + (i + 0.5) voxel inside the
 * rotated bounding box of link li at (r, t), clipped to [lo_limit, hi_limit]. */
static void link_voxel_box(const double *r, const double *t, const double *box_lo,
                           const double *box_hi, const double *origin, double voxel,
                           const int64_t *lo_limit, const int64_t *hi_limit, int64_t *lo,
                           int64_t *hi)
{
    for (int a = 0; a < 3; ++a) {
        double c = t[a], e = 0.0;
        for (int b = 0; b < 3; ++b) {
            c += r[3 * a + b] * 0.5 * (box_lo[b] + box_hi[b]);
            e += fabs(r[3 * a + b]) * 0.5 * (box_hi[b] - box_lo[b]);
        }
        lo[a] = max64(lo_limit[a], to_index(ceil((c - e - origin[a]) / voxel - 0.5)));
        hi[a] = min64(hi_limit[a], to_index(floor((c + e - origin[a]) / voxel - 0.5)));
    }
}

/* Of the voxel centres z0 + (kk + 0.5) voxel of the column at base-frame offsets (px, py) from
 * the link origin, the range [*a, *b] within [lo, hi] outside of which every centre misses the
 * link's table: where all three link-frame coordinates are inside it, widened by a voxel each
 * way (rounding never drops a centre). Empty when *a > *b. */
static void link_column(const double *r, double px, double py, const double *lut_origin,
                        const int64_t *lut_shape, double lut_pitch, double z0, double voxel,
                        int64_t lo, int64_t hi, int64_t *a_out, int64_t *b_out)
{
    double z_lo = -INFINITY, z_hi = INFINITY;
    *a_out = 1, *b_out = 0;
    for (int m = 0; m < 3; ++m) {
        double c = r[6 + m];
        double a = r[m] * px + r[3 + m] * py - lut_origin[m];
        double extent = (double)lut_shape[m] * lut_pitch;
        if (fabs(c) < 1e-12) {
            if (a < -1e-9 || a > extent + 1e-9)
                return;
            continue;
        }
        double u = -a / c, v = (extent - a) / c;
        z_lo = fmax(z_lo, fmin(u, v));
        z_hi = fmin(z_hi, fmax(u, v));
    }
    if (z_lo > z_hi)
        return;
    *a_out = max64(to_index(floor((z_lo - z0) / voxel - 0.5)) - 1, lo);
    *b_out = min64(to_index(ceil((z_hi - z0) / voxel - 0.5)) + 1, hi);
}

/* Whether the base-frame offset p from the link origin is inside the link's table. */
static int in_link(const double *r, double px, double py, double pz, const uint8_t *data,
                   const int64_t *shape, const double *origin, double inv_pitch)
{
    int64_t gx = to_index(floor((r[0] * px + r[3] * py + r[6] * pz - origin[0]) * inv_pitch));
    if (gx < 0 || gx >= shape[0])
        return 0;
    int64_t gy = to_index(floor((r[1] * px + r[4] * py + r[7] * pz - origin[1]) * inv_pitch));
    if (gy < 0 || gy >= shape[1])
        return 0;
    int64_t gz = to_index(floor((r[2] * px + r[5] * py + r[8] * pz - origin[2]) * inv_pitch));
    if (gz < 0 || gz >= shape[2])
        return 0;
    return data[(gx * shape[1] + gy) * shape[2] + gz] != 0;
}

/* Add weights[s] to every free voxel whose centre is inside a link at sample s, once per
 * sample (stamp[v]: the last sample that added to v; samples are numbered from sample0). */
void advocc_accumulate(double *H, int64_t *stamp, const uint8_t *free_, const double *origin,
                       double voxel, const int64_t *grid_shape, int64_t n, int64_t L,
                       const double *R, const double *t, const double *weights, int64_t sample0,
                       const uint8_t *lut_data, const int64_t *lut_offset,
                       const int64_t *lut_shape, const double *lut_origin, double lut_pitch,
                       const double *box_lo, const double *box_hi)
{
    int64_t ny = grid_shape[1], nz = grid_shape[2];
    int64_t zero[3] = {0, 0, 0};
    int64_t top[3] = {grid_shape[0] - 1, grid_shape[1] - 1, grid_shape[2] - 1};
    double inv = 1.0 / lut_pitch;
    for (int64_t s = 0; s < n; ++s) {
        int64_t sid = sample0 + s;
        double w = weights[s];
        for (int64_t li = 0; li < L; ++li) {
            const double *r = R + 9 * (s * L + li), *tl = t + 3 * (s * L + li);
            const int64_t *shape = lut_shape + 3 * li;
            const double *lut_o = lut_origin + 3 * li;
            const uint8_t *data = lut_data + lut_offset[li];
            int64_t lo[3], hi[3];
            link_voxel_box(r, tl, box_lo + 3 * li, box_hi + 3 * li, origin, voxel, zero, top,
                           lo, hi);
            for (int64_t i = lo[0]; i <= hi[0]; ++i) {
                double px = origin[0] + ((double)i + 0.5) * voxel - tl[0];
                for (int64_t j = lo[1]; j <= hi[1]; ++j) {
                    double py = origin[1] + ((double)j + 0.5) * voxel - tl[1];
                    int64_t ka, kb;
                    link_column(r, px, py, lut_o, shape, lut_pitch, origin[2] - tl[2], voxel,
                                lo[2], hi[2], &ka, &kb);
                    for (int64_t k = ka; k <= kb; ++k) {
                        double pz = origin[2] + ((double)k + 0.5) * voxel - tl[2];
                        if (!in_link(r, px, py, pz, data, shape, lut_o, inv))
                            continue;
                        int64_t v = (i * ny + j) * nz + k;
                        if (free_[v] && stamp[v] != sid) {
                            stamp[v] = sid;
                            H[v] += w;
                        }
                    }
                }
            }
        }
    }
}

/* ---- cover: which candidate boxes touch which configurations ---------------------------- */

typedef struct {
    uint8_t *cover; /* (rows, n_cand), NULL with union_ */
    int64_t n_cand;
    const int64_t *starts, *cand_id, *near_z;
    const uint8_t *near;
    int64_t *stamp; /* read and written atomically: rows share it */
    int union_;
    const double *origin;
    double voxel;
    int64_t k, nx, ny, nz, L;
    const double *R, *t;
    tables_t tables;
} cover_t;

/* One configuration s of row `row` (configurations.py's _cover docstring says what). */
static void cover_one(const cover_t *c, int64_t row, int64_t s)
{
    int64_t k = c->k, nx = c->nx, ny = c->ny, nz = c->nz;
    int64_t py_ = ny + 2 * k, pz_ = nz + 2 * k; /* the padded arrays' shape */
    int64_t lo_limit[3] = {-k, -k, -k}, hi_limit[3] = {nx - 1 + k, ny - 1 + k, nz - 1 + k};
    double inv = 1.0 / c->tables.pitch;
    for (int64_t li = 0; li < c->L; ++li) {
        const double *r = c->R + 9 * (s * c->L + li), *tl = c->t + 3 * (s * c->L + li);
        const int64_t *shape = c->tables.shape + 3 * li;
        const double *lut_o = c->tables.origin + 3 * li;
        const uint8_t *data = c->tables.data + c->tables.offset[li];
        int64_t lo[3], hi[3];
        link_voxel_box(r, tl, c->tables.box_lo + 3 * li, c->tables.box_hi + 3 * li, c->origin,
                       c->voxel, lo_limit, hi_limit, lo, hi);
        for (int64_t i = lo[0]; i <= hi[0]; ++i) {
            double px = c->origin[0] + ((double)i + 0.5) * c->voxel - tl[0];
            for (int64_t j = lo[1]; j <= hi[1]; ++j) {
                double py = c->origin[1] + ((double)j + 0.5) * c->voxel - tl[1];
                const int64_t *span = c->near_z + 2 * ((i + k) * py_ + (j + k));
                int64_t ka, kb;
                link_column(r, px, py, lut_o, shape, c->tables.pitch, c->origin[2] - tl[2],
                            c->voxel, max64(lo[2], span[0] - k), min64(hi[2], span[1] - k),
                            &ka, &kb);
                for (int64_t kk = ka; kk <= kb; ++kk) {
                    int64_t v = ((i + k) * py_ + (j + k)) * pz_ + (kk + k);
                    int64_t done = __atomic_load_n(&c->stamp[v], __ATOMIC_RELAXED);
                    if (!c->near[v] || done == row || (c->union_ && done >= 0))
                        continue;
                    double pz = c->origin[2] + ((double)kk + 0.5) * c->voxel - tl[2];
                    if (!in_link(r, px, py, pz, data, shape, lut_o, inv))
                        continue;
                    __atomic_store_n(&c->stamp[v], row, __ATOMIC_RELAXED);
                    if (c->union_)
                        continue;
                    uint8_t *out = c->cover + row * c->n_cand;
                    for (int64_t a0 = max64(i - k, 0); a0 <= min64(i + k, nx - 1); ++a0)
                        for (int64_t a1 = max64(j - k, 0); a1 <= min64(j + k, ny - 1); ++a1)
                            for (int64_t a2 = max64(kk - k, 0); a2 <= min64(kk + k, nz - 1);
                                 ++a2) {
                                int64_t cid = c->cand_id[(a0 * ny + a1) * nz + a2];
                                if (cid >= 0)
                                    out[cid] = 1;
                            }
                }
            }
        }
    }
}

static void cover_row(void *context, int64_t row)
{
    const cover_t *c = context;
    for (int64_t s = c->starts[row]; s < c->starts[row + 1]; ++s)
        cover_one(c, row, s);
}

void advocc_cover(uint8_t *cover, int64_t n_cand, int64_t rows, const int64_t *starts,
                  const int64_t *cand_id, int64_t nx, int64_t ny, int64_t nz,
                  const uint8_t *near, const int64_t *near_z, int64_t *stamp, int64_t union_,
                  const double *origin, double voxel, int64_t k, int64_t L, const double *R,
                  const double *t, const uint8_t *lut_data, const int64_t *lut_offset,
                  const int64_t *lut_shape, const double *lut_origin, double lut_pitch,
                  const double *box_lo, const double *box_hi, int64_t threads)
{
    cover_t c = {cover, n_cand, starts, cand_id, near_z, near, stamp, (int)union_, origin,
                 voxel, k, nx, ny, nz, L, R, t,
                 {lut_data, lut_offset, lut_shape, lut_origin, lut_pitch, box_lo, box_hi}};
    parallel_rows(rows, threads, 1, cover_row, &c);
}

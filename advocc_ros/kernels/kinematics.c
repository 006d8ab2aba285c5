/* Batched kinematics of a serial chain (kinematics/batch.py): forward kinematics of many
 * configurations, the goal region's pose test and damped-least-squares IK, one row a
 * configuration. Transforms are row-major 4x4 doubles; every sum is taken in the order the
 * comments give, so results do not depend on the compiler's choices (no -ffast-math). */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "parallel.h"

#define AT(M, a, b) ((M)[4 * (a) + (b)])
#define MAX_JOINTS 64 /* joints of a chain and entries of q: kernels/__init__.py's MAX_JOINTS */

typedef struct {
    int64_t nj, nq;
    const double *T_pj;      /* (nj, 4, 4) joint placements in their parents */
    const double *axis;      /* (nj, 3) unit axes */
    const uint8_t *revolute; /* (nj,) */
    const int64_t *index_q;  /* (nj,) */
    const double *T_jf;      /* (4, 4) frame in its joint */
} chain_t;

typedef struct {
    const double *T_center, *T_link_tool, *pos_tol, *rot_tol;
} pose_box_t;

/* out = A B for rigid transforms; out may be A. */
static void mul4(const double *A, const double *B, double *out)
{
    for (int a = 0; a < 3; ++a) {
        double r0 = AT(A, a, 0), r1 = AT(A, a, 1), r2 = AT(A, a, 2), r3 = AT(A, a, 3);
        for (int b = 0; b < 4; ++b)
            AT(out, a, b) = r0 * AT(B, 0, b) + r1 * AT(B, 1, b) + r2 * AT(B, 2, b)
                            + (b == 3 ? r3 : 0.0);
    }
    AT(out, 3, 0) = 0.0, AT(out, 3, 1) = 0.0, AT(out, 3, 2) = 0.0, AT(out, 3, 3) = 1.0;
}

/* The joint's motion at x: a rotation about the unit axis (Rodrigues) or a translation. */
static void joint_motion(const double *axis, int revolute, double x, double *M)
{
    memset(M, 0, 16 * sizeof(double));
    AT(M, 3, 3) = 1.0;
    if (revolute) {
        double wx = axis[0] * x, wy = axis[1] * x, wz = axis[2] * x;
        double th = sqrt(wx * wx + wy * wy + wz * wz), sa, sb;
        if (th < 1e-8) {
            sa = 1.0 - th * th / 6.0, sb = 0.5 - th * th / 24.0;
        } else {
            sa = sin(th) / th, sb = (1.0 - cos(th)) / (th * th);
        }
        AT(M, 0, 0) = 1.0 + sb * (wx * wx - th * th);
        AT(M, 1, 1) = 1.0 + sb * (wy * wy - th * th);
        AT(M, 2, 2) = 1.0 + sb * (wz * wz - th * th);
        AT(M, 0, 1) = -sa * wz + sb * wx * wy, AT(M, 1, 0) = sa * wz + sb * wx * wy;
        AT(M, 0, 2) = sa * wy + sb * wx * wz, AT(M, 2, 0) = -sa * wy + sb * wx * wz;
        AT(M, 1, 2) = -sa * wx + sb * wy * wz, AT(M, 2, 1) = sa * wx + sb * wy * wz;
    } else {
        for (int a = 0; a < 3; ++a) {
            AT(M, a, a) = 1.0;
            AT(M, a, 3) = axis[a] * x;
        }
    }
}

/* T_base_frame at q into T, each joint's origin and axis in the base frame (for jacobian). */
static void fk(const chain_t *c, const double *q, double *T, double *origins, double *axes_w)
{
    double M[16];
    memset(T, 0, 16 * sizeof(double));
    for (int a = 0; a < 4; ++a)
        AT(T, a, a) = 1.0;
    for (int64_t j = 0; j < c->nj; ++j) {
        const double *ax = c->axis + 3 * j;
        mul4(T, c->T_pj + 16 * j, T);
        for (int a = 0; a < 3; ++a) {
            origins[3 * j + a] = AT(T, a, 3);
            axes_w[3 * j + a] = AT(T, a, 0) * ax[0] + AT(T, a, 1) * ax[1] + AT(T, a, 2) * ax[2];
        }
        joint_motion(ax, c->revolute[j], q[c->index_q[j]], M);
        mul4(T, M, T);
    }
    mul4(T, c->T_jf, T);
}

/* The LOCAL frame Jacobian (6, nq), rows (linear, angular), from fk's outputs. */
static void jacobian(const chain_t *c, const double *T, const double *origins,
                     const double *axes_w, double *J)
{
    int64_t nq = c->nq;
    memset(J, 0, 6 * nq * sizeof(double));
    for (int64_t j = 0; j < c->nj; ++j) {
        int64_t col = c->index_q[j];
        const double *aw = axes_w + 3 * j;
        if (c->revolute[j]) {
            double dx = AT(T, 0, 3) - origins[3 * j], dy = AT(T, 1, 3) - origins[3 * j + 1],
                   dz = AT(T, 2, 3) - origins[3 * j + 2];
            double cx = aw[1] * dz - aw[2] * dy, cy = aw[2] * dx - aw[0] * dz,
                   cz = aw[0] * dy - aw[1] * dx;
            for (int a = 0; a < 3; ++a) {
                J[a * nq + col] = AT(T, 0, a) * cx + AT(T, 1, a) * cy + AT(T, 2, a) * cz;
                J[(3 + a) * nq + col] = AT(T, 0, a) * aw[0] + AT(T, 1, a) * aw[1]
                                        + AT(T, 2, a) * aw[2];
            }
        } else {
            for (int a = 0; a < 3; ++a)
                J[a * nq + col] = AT(T, 0, a) * aw[0] + AT(T, 1, a) * aw[1]
                                  + AT(T, 2, a) * aw[2];
        }
    }
}

/* Rotation vector of the row-major 3x3 R, stable near a half turn. */
static void log3(const double *R, double *out)
{
    double cos_ = fmin(fmax((R[0] + R[4] + R[8] - 1.0) / 2.0, -1.0), 1.0);
    double theta = acos(cos_);
    double vx = R[7] - R[5], vy = R[2] - R[6], vz = R[3] - R[1];
    if (theta < 1e-6) {
        double scale = 0.5 + theta * theta / 12.0;
        out[0] = vx * scale, out[1] = vy * scale, out[2] = vz * scale;
    } else if (theta < M_PI - 1e-4) {
        double scale = theta / (2.0 * sin(theta));
        out[0] = vx * scale, out[1] = vy * scale, out[2] = vz * scale;
    } else {
        double one_minus = 1.0 - cos_;
        int i = 0;
        for (int a = 1; a < 3; ++a)
            if (R[4 * a] > R[4 * i])
                i = a;
        double ai = sqrt(fmax((R[4 * i] - cos_) / one_minus, 0.0));
        for (int a = 0; a < 3; ++a)
            out[a] = a == i ? ai : (R[3 * i + a] + R[3 * a + i]) / (2.0 * one_minus * ai);
        if (out[0] * vx + out[1] * vy + out[2] * vz < 0.0)
            for (int a = 0; a < 3; ++a)
                out[a] = -out[a];
        for (int a = 0; a < 3; ++a)
            out[a] *= theta;
    }
}

/* Whether the link pose T puts the tool in the pose box (kinematics.batch.PoseBox). */
static int in_box(const double *T, const pose_box_t *box)
{
    double tool[16], Rrel[9], w[3];
    const double *C = box->T_center;
    mul4(T, box->T_link_tool, tool);
    for (int a = 0; a < 3; ++a) {
        double d = 0.0;
        for (int b = 0; b < 3; ++b)
            d += AT(C, b, a) * (AT(tool, b, 3) - AT(C, b, 3));
        if (fabs(d) > box->pos_tol[a])
            return 0;
    }
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
            Rrel[3 * a + b] = AT(C, 0, a) * AT(tool, 0, b) + AT(C, 1, a) * AT(tool, 1, b)
                              + AT(C, 2, a) * AT(tool, 2, b);
    log3(Rrel, w);
    for (int a = 0; a < 3; ++a)
        if (fabs(w[a]) > box->rot_tol[a])
            return 0;
    return 1;
}

/* (linear, angular) twist of the rigid transform E (rows 0-2 read), as pinocchio's log6. */
static void log6(const double *E, double *twist)
{
    double Rs[9], w[3];
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
            Rs[3 * a + b] = AT(E, a, b);
    log3(Rs, w);
    double th = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    double c = th < 1e-6 ? 1.0 / 12.0
                         : (1.0 - th * sin(th) / (2.0 * (1.0 - cos(th)))) / (th * th);
    double p0 = AT(E, 0, 3), p1 = AT(E, 1, 3), p2 = AT(E, 2, 3);
    /* V^-1 p = p - 0.5 w x p + c w x (w x p) */
    double x0 = w[1] * p2 - w[2] * p1, x1 = w[2] * p0 - w[0] * p2, x2 = w[0] * p1 - w[1] * p0;
    double y0 = w[1] * x2 - w[2] * x1, y1 = w[2] * x0 - w[0] * x2, y2 = w[0] * x1 - w[1] * x0;
    twist[0] = p0 - 0.5 * x0 + c * y0, twist[1] = p1 - 0.5 * x1 + c * y1;
    twist[2] = p2 - 0.5 * x2 + c * y2;
    twist[3] = w[0], twist[4] = w[1], twist[5] = w[2];
}

/* x = (J J^T + damping I)^-1 err by Cholesky; J (6, nq). */
static void damped_solve(const double *J, int64_t nq, const double *err, double damping,
                         double *x)
{
    double A[36];
    for (int a = 0; a < 6; ++a)
        for (int b = 0; b <= a; ++b) {
            double v = 0.0;
            for (int64_t c = 0; c < nq; ++c)
                v += J[a * nq + c] * J[b * nq + c];
            A[6 * a + b] = v + (a == b ? damping : 0.0);
        }
    for (int a = 0; a < 6; ++a)
        for (int b = 0; b <= a; ++b) {
            double v = A[6 * a + b];
            for (int c = 0; c < b; ++c)
                v -= A[6 * a + c] * A[6 * b + c];
            A[6 * a + b] = a == b ? sqrt(v) : v / A[6 * b + b];
        }
    for (int a = 0; a < 6; ++a) {
        double v = err[a];
        for (int c = 0; c < a; ++c)
            v -= A[6 * a + c] * x[c];
        x[a] = v / A[6 * a + a];
    }
    for (int a = 5; a >= 0; --a) {
        double v = x[a];
        for (int c = a + 1; c < 6; ++c)
            v -= A[6 * c + a] * x[c];
        x[a] = v / A[6 * a + a];
    }
}

/* ---- frames: T_base_frame of every row ---------------------------------------------- */

typedef struct {
    chain_t chain;
    const double *Q;
    double *out;
} frames_t;

static void frames_row(void *context, int64_t i)
{
    frames_t *f = context;
    double origins[3 * MAX_JOINTS], axes_w[3 * MAX_JOINTS];
    fk(&f->chain, f->Q + i * f->chain.nq, f->out + 16 * i, origins, axes_w);
}

void advocc_frames(int64_t n, int64_t nj, int64_t nq, const double *Q, const double *T_pj,
                   const double *axis, const uint8_t *revolute, const int64_t *index_q,
                   const double *T_jf, double *out, int64_t threads)
{
    frames_t f = {{nj, nq, T_pj, axis, revolute, index_q, T_jf}, Q, out};
    parallel_rows(n, threads, 256, frames_row, &f);
}

/* ---- link_frames: T_base_geometry of each link of every row, one thread ---------------- */

/* T_base_joint of every joint at q into row (nj, 4, 4), each joint after its parent
 * (parent[j] = -1: the base). */
static void joint_frames(int64_t nj, const double *q, const int64_t *parent, const double *T_pj,
                         const double *axis, const uint8_t *revolute, const int64_t *index_q,
                         double *row)
{
    double M[16];
    for (int64_t j = 0; j < nj; ++j) {
        double *T = row + 16 * j;
        if (parent[j] < 0)
            memcpy(T, T_pj + 16 * j, 16 * sizeof(double));
        else
            mul4(row + 16 * parent[j], T_pj + 16 * j, T);
        joint_motion(axis + 3 * j, revolute[j], q[index_q[j]], M);
        mul4(T, M, T);
    }
}

/* The joints' frames of each row (into scratch, (nj + 1) x 16 with the base last), then each
 * link's T = T_base_joint[column[l]] placement[l]. */
void advocc_link_frames(int64_t n, int64_t nj, int64_t nq, const double *Q,
                        const int64_t *parent, const double *T_pj, const double *axis,
                        const uint8_t *revolute, const int64_t *index_q, int64_t n_links,
                        const int64_t *column, const double *placements, double *scratch,
                        double *out)
{
    double *base = scratch + 16 * nj;
    memset(base, 0, 16 * sizeof(double));
    for (int a = 0; a < 4; ++a)
        AT(base, a, a) = 1.0;
    for (int64_t i = 0; i < n; ++i) {
        joint_frames(nj, Q + i * nq, parent, T_pj, axis, revolute, index_q, scratch);
        for (int64_t l = 0; l < n_links; ++l)
            mul4(scratch + 16 * column[l], placements + 16 * l, out + 16 * (i * n_links + l));
    }
}

/* ---- contains: the pose box test of every link pose ------------------------------------- */

typedef struct {
    pose_box_t box;
    const double *T_links;
    uint8_t *out;
} contains_t;

static void contains_row(void *context, int64_t i)
{
    contains_t *c = context;
    c->out[i] = (uint8_t)in_box(c->T_links + 16 * i, &c->box);
}

void advocc_contains(int64_t n, const double *T_links, const double *T_center,
                     const double *T_link_tool, const double *pos_tol, const double *rot_tol,
                     uint8_t *out, int64_t threads)
{
    contains_t c = {{T_center, T_link_tool, pos_tol, rot_tol}, T_links, out};
    parallel_rows(n, threads, 1024, contains_row, &c);
}

/* ---- dls: damped least squares, each row its own attempt -------------------------------- */

typedef struct {
    chain_t chain;
    pose_box_t box;
    double *Q;
    uint8_t *done;
    const double *T_target, *lower, *upper;
    const int64_t *iterations;
    double damping, max_step;
} dls_t;

static void dls_row(void *context, int64_t i)
{
    dls_t *d = context;
    const chain_t *c = &d->chain;
    int64_t nq = c->nq, nj = c->nj;
    double T[16], E[16], err[6], x[6];
    double J[6 * MAX_JOINTS], origins[3 * MAX_JOINTS], axes_w[3 * MAX_JOINTS], dq[MAX_JOINTS];
    double *q = d->Q + i * nq;
    const double *target = d->T_target + 16 * i;
    for (int64_t step = 0; step <= d->iterations[i]; ++step) {
        fk(c, q, T, origins, axes_w);
        if (in_box(T, &d->box)) {
            d->done[i] = 1;
            break;
        }
        if (step >= d->iterations[i])
            break;
        jacobian(c, T, origins, axes_w, J);
        for (int a = 0; a < 3; ++a) /* E = T^-1 T_target (rows 0-2) */
            for (int b = 0; b < 4; ++b) {
                double v = 0.0;
                for (int k = 0; k < 3; ++k)
                    v += AT(T, k, a) * (AT(target, k, b) - (b == 3 ? AT(T, k, 3) : 0.0));
                AT(E, a, b) = v;
            }
        log6(E, err);
        damped_solve(J, nq, err, d->damping, x);
        double norm = 0.0;
        for (int64_t k = 0; k < nq; ++k) {
            double v = 0.0;
            for (int a = 0; a < 6; ++a)
                v += J[a * nq + k] * x[a];
            dq[k] = v;
            norm += v * v;
        }
        double scale = fmin(1.0, d->max_step / fmax(sqrt(norm), 1e-300));
        for (int64_t k = 0; k < nq; ++k)
            q[k] = fmin(fmax(q[k] + dq[k] * scale, d->lower[k]), d->upper[k]);
    }
}

void advocc_dls(int64_t n, int64_t nj, int64_t nq, double *Q, uint8_t *done,
                const double *T_target, const int64_t *iterations, double damping,
                double max_step, const double *lower, const double *upper, const double *T_pj,
                const double *axis, const uint8_t *revolute, const int64_t *index_q,
                const double *T_jf, const double *T_center, const double *T_link_tool,
                const double *pos_tol, const double *rot_tol, int64_t threads)
{
    dls_t d = {{nj, nq, T_pj, axis, revolute, index_q, T_jf},
               {T_center, T_link_tool, pos_tol, rot_tol},
               Q, done, T_target, lower, upper, iterations, damping, max_step};
    parallel_rows(n, threads, 1, dls_row, &d);
}

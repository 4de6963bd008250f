/*
 * tse2_reference.c: a hand-written C99 step of the TSE(2) second-order minimum-energy filter, the yardstick of
 * benchmarks/bench_tse2.py (issue 9). No autodiff: every term is the closed form below.
 *
 * What it reproduces, to round-off: liemef.MinimumEnergyFilter(PlanarRigidBody(), connection="zero",
 * order="second", integrator="rkmk4" | "lie-euler", alpha=0, substeps=1), samples held over each interval,
 * every measurement component present. The system is the default PlanarRigidBody (Rigo et al. 2022, Sec. VI):
 * J = 6.125, m = 125, l = 0.2, B = [0; 0.1 I3], R = B'B, D = diag(0.5 x4, 0.1 x3), Q = D'D, sensor "gps_imu".
 *
 * State, laid out as liemef's TSE2 leaves: g[7] = (cos theta, sin theta, x, y, omega, vx, vy) (SE2.cos_sin_xy,
 * then R3.x); K[36], the 6 x 6 gain, row-major, algebra order (omega, vx, vy; omega, vx, vy). K must be
 * symmetric: it stays so under the (0)-connection, and the code computes one triangle and mirrors it.
 *
 * Equations (Saccon et al. 2016, Theorem 4.1; docs/theorem.md), with c = 1/2:
 *   g^-1 g_dot = lambda + K r
 *   K_dot      = M K + K M' - K E K + B R^-1 B',   M = A - W   (alpha = 0; K symmetric, so K M' = (M K)')
 * Closed forms (Rigo et al. 2022, Prop. 1; tests/paper_forms.py: rigo2022_tse2_terms):
 *   h       = (x + l c, y + l s, x - l c, y - l s, omega, vx, vy)                       eq. (13)
 *   ytilde  = D^-T Q D^-1 (y - h) = diag(w_a x4, w_3, w_4, w_4) (y - h)                 eq. (23)
 *   r       = (-l s (yt1 - yt3) + l c (yt2 - yt4),  c (yt1 + yt3) + s (yt2 + yt4),
 *              -s (yt1 + yt3) + c (yt2 + yt4),  yt5, yt6, yt7)                             eq. (22)
 *   lambda  = (omega, vx, vy, u_w / J, omega vy + u_v / m, -omega vx)                     eqs. (8), (11)
 *   A       = [[-ad_Omega, I3], [0, dV]], ad_Omega = [[0,0,0],[vy,0,-w],[-vx,w,0]],
 *             dV = [[0,0,0],[vy,0,w],[-vx,-w,0]]                                          eq. (25)
 *   E       = [[E1, 0], [0, diag(w_3, w_4, w_4)]],
 *             E1 = [[a11, a12, a13], [a12, 2 w_a, 0], [a13, 0, 2 w_a]],
 *             a11 = l c (yt1 - yt3) + l s (yt2 - yt4) + 2 l^2 w_a,
 *             a12 = (s (yt1 + yt3) - c (yt2 + yt4)) / 2,  a13 = (c (yt1 + yt3) + s (yt2 + yt4)) / 2
 *             eq. (26) with the weights of eq. (35), and with a21 = a12, a31 = a13: Theorem 4.1's E is
 *             symmetric; the printed a21, a31 have the wrong sign (docs/errata.md)
 *   W       = blockdiag(ad_{(K r)_{1:3}} / 2, 0)                                           eq. (27)
 *   B R^-1 B' = blockdiag(0, B2 (B2' B2)^-1 B2') = blockdiag(0, I3)                        Sec. IV, eq. (27)
 * With Q = D'D the weights are w_a = w_3 = w_4 = 1 (D^-T Q D^-1 = I).
 *
 * Integrators (src/liemef/filter/_integrators.py), one step of size dt per sample interval:
 *   Lie-Euler: g <- g exp(dt xi), K <- K + dt K_dot.
 *   RKMK4: classical RK4 on (theta, K) with g = g0 exp(theta), the stage velocities mapped through
 *   dexp^-1_{-theta} xi = xi + [theta, xi] / 2 + [theta, [theta, xi]] / 12; the bracket is nonzero on se(2) only.
 * exp on SE(2) is SE2.exp: rotation by w, translation V(w) v with V = [[a, -b], [b, a]], a = sin(w)/w,
 * b = (1 - cos w)/w, and the same Taylor branch for |w| < 1e-2.
 *
 * Written for speed at -O2: fixed sizes, no heap; M K and E K are formed from the few nonzero entries of M = A - W
 * and E (their zero blocks are known); one triangle of K_dot; reciprocals multiplied rather than divided by.
 *
 * Build: cc -std=c99 -O2 -fPIC -shared tse2_reference.c -o libtse2_reference.so -lm (benchmarks/c_reference.py).
 */

#include <math.h>
#include <stddef.h>

#define TSE2_REF_LIE_EULER 0
#define TSE2_REF_RKMK4 1

/* PlanarRigidBody() defaults (Rigo et al. 2022, Sec. VI). */
#define INERTIA 6.125
#define MASS 125.0
#define ARM 0.2
/* D^-T Q D^-1 with Q = D'D: the identity (antennas, gyro, velocity sensor). */
#define W_A 1.0
#define W_3 1.0
#define W_4 1.0
/* B R^-1 B' with B = [0; B2], R = B'B: blockdiag(0, I3). */
#define BRB_V 1.0

#define TAYLOR 1e-2 /* |w| below which exp uses its series, as SE2.exp */

/* out = g exp(xi) (liemef's rplus). out may alias g. */
static void rplus(const double *g, const double *xi, double *out)
{
    const double c = g[0], s = g[1], x = g[2], y = g[3];
    const double w = xi[0], w2 = w * w;
    const double ce = cos(w), se = sin(w);
    double a, b;
    if (fabs(w) < TAYLOR) {
        a = 1.0 - w2 * (1.0 / 6.0) + w2 * w2 * (1.0 / 120.0) - w2 * w2 * w2 * (1.0 / 5040.0);
        b = w * 0.5 - w * w2 * (1.0 / 24.0) + w * w2 * w2 * (1.0 / 720.0) - w * w2 * w2 * w2 * (1.0 / 40320.0);
    } else {
        const double sh = sin(w / 2.0);
        a = se / w;
        b = 2.0 * sh * sh / w;
    }
    const double p0 = a * xi[1] - b * xi[2], p1 = b * xi[1] + a * xi[2];
    out[0] = c * ce - s * se;
    out[1] = s * ce + c * se;
    out[2] = c * p0 - s * p1 + x;
    out[3] = s * p0 + c * p1 + y;
    out[4] = g[4] + xi[3];
    out[5] = g[5] + xi[4];
    out[6] = g[6] + xi[5];
}

/* The filter's vector field at (g, K) with the held sample (u, y): xi = lambda + K r and Kd = K_dot. */
static void field(const double *g, const double *K, const double *u, const double *y, double *xi, double *Kd)
{
    const double c = g[0], s = g[1], w = g[4], vx = g[5], vy = g[6];
    const double lc = ARM * c, ls = ARM * s;
    double r[6], P[36], N[36];
    int i, j, k;

    /* weighted innovation, eq. (23) */
    const double e1 = W_A * (y[0] - (g[2] + lc)), e2 = W_A * (y[1] - (g[3] + ls));
    const double e3 = W_A * (y[2] - (g[2] - lc)), e4 = W_A * (y[3] - (g[3] - ls));
    const double sx = e1 + e3, sy = e2 + e4, dx = e1 - e3, dy = e2 - e4;

    /* residual, eq. (22) */
    r[0] = -ls * dx + lc * dy;
    r[1] = c * sx + s * sy;
    r[2] = -s * sx + c * sy;
    r[3] = W_3 * (y[4] - w);
    r[4] = W_4 * (y[5] - vx);
    r[5] = W_4 * (y[6] - vy);

    /* xi = lambda + K r, eqs. (8), (11) */
    {
        double Kr[6];
        for (i = 0; i < 6; i++) {
            const double *Ki = K + 6 * i;
            Kr[i] = Ki[0] * r[0] + Ki[1] * r[1] + Ki[2] * r[2] + Ki[3] * r[3] + Ki[4] * r[4] + Ki[5] * r[5];
        }
        xi[0] = w + Kr[0];
        xi[1] = vx + Kr[1];
        xi[2] = vy + Kr[2];
        xi[3] = u[0] * (1.0 / INERTIA) + Kr[3];
        xi[4] = w * vy + u[1] * (1.0 / MASS) + Kr[4];
        xi[5] = -w * vx + Kr[5];

        /* P = M K with M = A - W (eqs. (25), (27)); M's nonzero entries:
         *   M[1][0] = -vy - Kr2/2, M[1][2] = w + Kr0/2, M[2][0] = vx + Kr1/2, M[2][1] = -w - Kr0/2,
         *   M[0..2][3..5] = I3, M[4][3] = vy, M[4][5] = w, M[5][3] = -vx, M[5][4] = -w. */
        const double m10 = -vy - 0.5 * Kr[2], m12 = w + 0.5 * Kr[0];
        const double m20 = vx + 0.5 * Kr[1], m21 = -w - 0.5 * Kr[0];
        for (j = 0; j < 6; j++) {
            const double k0 = K[j], k1 = K[6 + j], k2 = K[12 + j], k3 = K[18 + j], k4 = K[24 + j],
                         k5 = K[30 + j];
            P[j] = k3;
            P[6 + j] = m10 * k0 + m12 * k2 + k4;
            P[12 + j] = m20 * k0 + m21 * k1 + k5;
            P[18 + j] = 0.0;
            P[24 + j] = vy * k3 + w * k5;
            P[30 + j] = -vx * k3 - w * k4;
        }
    }

    /* N = E K, E of eq. (26)/(35) with a21 = a12, a31 = a13 */
    {
        const double a11 = lc * dx + ls * dy + 2.0 * ARM * ARM * W_A;
        const double a12 = 0.5 * (s * sx - c * sy), a13 = 0.5 * (c * sx + s * sy);
        const double e22 = 2.0 * W_A;
        for (j = 0; j < 6; j++) {
            const double k0 = K[j], k1 = K[6 + j], k2 = K[12 + j];
            N[j] = a11 * k0 + a12 * k1 + a13 * k2;
            N[6 + j] = a12 * k0 + e22 * k1;
            N[12 + j] = a13 * k0 + e22 * k2;
            N[18 + j] = W_3 * K[18 + j];
            N[24 + j] = W_4 * K[24 + j];
            N[30 + j] = W_4 * K[30 + j];
        }
    }

    /* K_dot = P + P' - K N + B R^-1 B' on the upper triangle, mirrored. K N is formed in full rows: the row
     * loops vectorize, which is faster than accumulating the triangle alone. */
    {
        double KN[36];
        for (i = 0; i < 6; i++) {
            const double *Ki = K + 6 * i;
            double *o = KN + 6 * i;
            for (j = 0; j < 6; j++)
                o[j] = Ki[0] * N[j];
            for (k = 1; k < 6; k++)
                for (j = 0; j < 6; j++)
                    o[j] += Ki[k] * N[6 * k + j];
        }
        for (i = 0; i < 6; i++)
            for (j = i; j < 6; j++) {
                double v = P[6 * i + j] + P[6 * j + i] - KN[6 * i + j];
                if (i == j && i >= 3)
                    v += BRB_V;
                Kd[6 * i + j] = v;
                Kd[6 * j + i] = v;
            }
    }
}

/* dexp^-1_{-theta} xi truncated at order 4 (RKMK4), times dt: out = dt (xi + ad_th xi / 2 + ad_th^2 xi / 12). */
static void dexpinv_dt(const double *th, const double *xi, double dt, double *out)
{
    /* ad_th = [[0,0,0],[th2,0,-th0],[-th1,th0,0]] on se(2), 0 on R^3 */
    const double a1 = 0.0, a2 = th[2] * xi[0] - th[0] * xi[2], a3 = -th[1] * xi[0] + th[0] * xi[1];
    const double b2 = th[2] * a1 - th[0] * a3, b3 = -th[1] * a1 + th[0] * a2;
    out[0] = dt * xi[0];
    out[1] = dt * (xi[1] + 0.5 * a2 + b2 * (1.0 / 12.0));
    out[2] = dt * (xi[2] + 0.5 * a3 + b3 * (1.0 / 12.0));
    out[3] = dt * xi[3];
    out[4] = dt * xi[4];
    out[5] = dt * xi[5];
}

/* One Lie-Euler step of size dt from time t (the field does not depend on t), in place. */
void tse2_ref_step_lie_euler(double *g, double *K, double t, double dt, const double *u, const double *y)
{
    double xi[6], Kd[36], h[6];
    int i;
    (void)t;
    field(g, K, u, y, xi, Kd);
    for (i = 0; i < 6; i++)
        h[i] = dt * xi[i];
    rplus(g, h, g);
    for (i = 0; i < 36; i++)
        K[i] += dt * Kd[i];
}

/* One RKMK4 step of size dt from time t, in place. */
void tse2_ref_step_rkmk4(double *g, double *K, double t, double dt, const double *u, const double *y)
{
    double xi[6], k1[6], k2[6], k3[6], k4[6], half[6], th[6];
    double L1[36], L2[36], L3[36], L4[36], Ks[36], gs[7];
    int i;
    (void)t;

    field(g, K, u, y, xi, L1);
    for (i = 0; i < 6; i++) {
        k1[i] = dt * xi[i];
        half[i] = 0.5 * k1[i];
    }
    rplus(g, half, gs);
    for (i = 0; i < 36; i++)
        Ks[i] = K[i] + 0.5 * dt * L1[i];

    field(gs, Ks, u, y, xi, L2);
    dexpinv_dt(half, xi, dt, k2);
    for (i = 0; i < 6; i++)
        half[i] = 0.5 * k2[i];
    rplus(g, half, gs);
    for (i = 0; i < 36; i++)
        Ks[i] = K[i] + 0.5 * dt * L2[i];

    field(gs, Ks, u, y, xi, L3);
    dexpinv_dt(half, xi, dt, k3);
    rplus(g, k3, gs);
    for (i = 0; i < 36; i++)
        Ks[i] = K[i] + dt * L3[i];

    field(gs, Ks, u, y, xi, L4);
    dexpinv_dt(k3, xi, dt, k4);

    for (i = 0; i < 6; i++)
        th[i] = (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) * (1.0 / 6.0);
    rplus(g, th, g);
    for (i = 0; i < 36; i++)
        K[i] += (dt * (1.0 / 6.0)) * (L1[i] + 2.0 * L2[i] + 2.0 * L3[i] + L4[i]);
}

/*
 * n sample intervals [ts[k], ts[k+1]], k = 0..n-1, with the samples us[2k..2k+1], ys[7k..7k+6] held over each
 * (liemef's run: sample k is used over [ts[k], ts[k+1])). ts has n + 1 entries. (g, K) is the initial state
 * and holds the final one on return. g_out ((n+1) x 7) and K_out ((n+1) x 36) receive the trajectory, the
 * initial state first, as liemef's Trajectory; either may be NULL. Returns 0, or -1 for an unknown integrator.
 */
int tse2_ref_run(int integrator, int n, const double *ts, const double *us, const double *ys, double *g, double *K,
                 double *g_out, double *K_out)
{
    int k, i;
    if (integrator != TSE2_REF_RKMK4 && integrator != TSE2_REF_LIE_EULER)
        return -1;
    for (k = 0;; k++) {
        if (g_out != NULL)
            for (i = 0; i < 7; i++)
                g_out[7 * (size_t)k + i] = g[i];
        if (K_out != NULL)
            for (i = 0; i < 36; i++)
                K_out[36 * (size_t)k + i] = K[i];
        if (k == n)
            break;
        if (integrator == TSE2_REF_RKMK4)
            tse2_ref_step_rkmk4(g, K, ts[k], ts[k + 1] - ts[k], us + 2 * (size_t)k, ys + 7 * (size_t)k);
        else
            tse2_ref_step_lie_euler(g, K, ts[k], ts[k + 1] - ts[k], us + 2 * (size_t)k, ys + 7 * (size_t)k);
    }
    return 0;
}

/* The ROS34PW2 sub-step of fmu_plant/rosenbrock.py, compiled (optional; the Python closure is the
 * definition and the fallback).
 *
 * Every expression below is the Python one of rosenbrock.build_model, operand for operand and in the
 * same order, so that IEEE-754 double arithmetic gives the same bits: Python's float operations are
 * single correctly rounded operations, exp/log1p/pow come from the same C library, sqrt is correctly
 * rounded everywhere. This holds only without contraction into fused multiply-adds and without
 * reassociation: build with -ffp-contract=off and never with -ffast-math (setup.py).
 * tests/test_rosenbrock_compiled.py checks the bits against the closure.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <string.h>

/* The constants of one plant, by name: build_model passes them in this order (it reads NAMES). */
#define CONSTANTS(X) \
    X(kq_leak) X(kq_open) X(n_char) X(lam) X(inv_sqrt_lam) X(pd) X(tau) \
    X(inv_l0) X(ga) X(gb) X(k_area) X(k_force) X(p_th) X(w_th) X(inv_w_th) X(f_lock0) X(inv_lock) \
    X(lock_exponent_max) X(k_rubber) X(damping) X(cos0) X(inv_sin0) X(f0) X(mu) X(up_factor) \
    X(down_factor) X(rate_gain) X(inv_v_ref) X(rate_exp) X(inv_delta) X(inv_tol_p) X(inv_tol_l) \
    X(inv_tol_v) X(inv_tol_z) X(a21) X(a31) X(a32) X(a41) X(a42) X(a43) X(c21) X(c31) X(c32) X(c41) \
    X(c42) X(c43) X(e1) X(e2) X(e3) X(e4) X(t2) X(t3) X(gamma) X(m_moving) X(gravity) X(cross_err) \
    X(cross_min_h) X(u_min) X(u_span) X(h_max) X(h_min) X(safety) X(growth) X(shrink) X(err_floor) \
    X(stretch) X(kink_floor) X(forced_max)

#define AS_FIELD(name) double name;
#define AS_STRING(name) #name,
#define COUNT(name) +1

typedef struct {
    CONSTANTS(AS_FIELD)
} Constants;

static const char *const constant_names[] = {CONSTANTS(AS_STRING) NULL};
enum { N_CONSTANTS = 0 CONSTANTS(COUNT) };

typedef struct {
    PyObject_HEAD
    Constants k;
    double kq_open_full; /* kq_open at full gate (set_gate scales it) */
    long long forced_total; /* sub-steps accepted over their tolerances since construction (forced_substeps) */
} ModelObject;

/* rhs(x, p, l, v, z, ps, w, inv_mass) of build_model; writes (dp, dl, dv, dz). */
static void rhs(const Constants *k, double x, double p, double l, double v, double z, double ps, double w,
                double inv_mass, double f[4]) {
    double xc = x < 0.0 ? 0.0 : x > 1.0 ? 1.0 : x;
    double k_in = k->kq_leak + k->kq_open * pow(xc, k->n_char);
    double k_out = k->kq_leak + k->kq_open * pow(1.0 - xc, k->n_char);
    double d = ps - p, q;
    if (d >= k->lam)
        q = k_in * sqrt(d);
    else if (d <= -k->lam)
        q = -k_in * sqrt(-d);
    else
        q = k_in * d * k->inv_sqrt_lam;
    d = p - k->pd;
    if (d >= k->lam)
        q -= k_out * sqrt(d);
    else if (d <= -k->lam)
        q += k_out * sqrt(-d);
    else
        q -= k_out * d * k->inv_sqrt_lam;
    double s = 1.0 - l * k->inv_l0;
    double g_area = k->ga * s * s - k->gb;
    if (g_area < 0.0)
        g_area = 0.0;
    double dp = q - k->k_area * g_area * v;
    double arg = (p - k->p_th) * k->inv_w_th;
    double p_eff = k->w_th * (arg > 0.0 ? arg + log1p(exp(-arg)) : log1p(exp(arg)));
    double force = k->k_force * p_eff * g_area - k->k_rubber * l - w - k->damping * v - z;
    if (k->f_lock0 != 0.0) {
        double e_lock = -l * k->inv_lock;
        force += k->f_lock0 * (e_lock < k->lock_exponent_max ? exp(e_lock) : INFINITY);
    }
    if (l <= 0.0 && v <= 0.0 && force <= 0.0) {
        f[0] = dp; f[1] = 0.0; f[2] = 0.0; f[3] = 0.0;
        return;
    }
    if (v > 0.0 || v < 0.0) {
        double c = k->cos0 * s;
        c = 1.0 - c * c;
        double contact = c > 0.0 ? sqrt(c) * k->inv_sin0 * s : 0.0;
        double level = p > 0.0 ? k->f0 + k->mu * p * contact : k->f0;
        double speed;
        if (v > 0.0) {
            speed = v;
            level *= k->up_factor;
        } else {
            speed = -v;
            level = -level * k->down_factor;
        }
        if (k->rate_gain > 0.0)
            level *= 1.0 + k->rate_gain * pow(speed * k->inv_v_ref, k->rate_exp);
        f[0] = dp; f[1] = v; f[2] = force * inv_mass; f[3] = speed * k->inv_delta * (level - z);
        return;
    }
    f[0] = dp; f[1] = v; f[2] = force * inv_mass; f[3] = 0.0;
}

/* jacobian(...) of build_model: (dp, dl, dv, dz) and the ten entries the scheme uses. */
static void jacobian(const Constants *k, double x, double p, double l, double v, double z, double ps,
                     double w, double inv_mass, double f[4], double j[10]) {
    double xc = x < 0.0 ? 0.0 : x > 1.0 ? 1.0 : x;
    double k_in = k->kq_leak + k->kq_open * pow(xc, k->n_char);
    double k_out = k->kq_leak + k->kq_open * pow(1.0 - xc, k->n_char);
    double d = ps - p, q, r, j_pp;
    if (d >= k->lam) {
        r = sqrt(d);
        q = k_in * r;
        j_pp = -0.5 * k_in / r;
    } else if (d <= -k->lam) {
        r = sqrt(-d);
        q = -k_in * r;
        j_pp = -0.5 * k_in / r;
    } else {
        q = k_in * d * k->inv_sqrt_lam;
        j_pp = -k_in * k->inv_sqrt_lam;
    }
    d = p - k->pd;
    if (d >= k->lam) {
        r = sqrt(d);
        q -= k_out * r;
        j_pp -= 0.5 * k_out / r;
    } else if (d <= -k->lam) {
        r = sqrt(-d);
        q += k_out * r;
        j_pp -= 0.5 * k_out / r;
    } else {
        q -= k_out * d * k->inv_sqrt_lam;
        j_pp -= k_out * k->inv_sqrt_lam;
    }
    double s = 1.0 - l * k->inv_l0;
    double g_area = k->ga * s * s - k->gb, dg_area;
    if (g_area > 0.0) {
        dg_area = -2.0 * k->ga * s * k->inv_l0;
    } else {
        g_area = dg_area = 0.0;
    }
    double dp = q - k->k_area * g_area * v;
    double arg = (p - k->p_th) * k->inv_w_th, ex, p_eff, slope;
    if (arg > 0.0) {
        ex = exp(-arg);
        p_eff = k->w_th * (arg + log1p(ex));
        slope = 1.0 / (1.0 + ex);
    } else {
        ex = exp(arg);
        p_eff = k->w_th * log1p(ex);
        slope = ex / (1.0 + ex);
    }
    double force = k->k_force * p_eff * g_area - k->k_rubber * l - w - k->damping * v - z;
    double dforce_dl = k->k_force * p_eff * dg_area - k->k_rubber;
    if (k->f_lock0 != 0.0) {
        double e_lock = -l * k->inv_lock;
        double lock = k->f_lock0 * (e_lock < k->lock_exponent_max ? exp(e_lock) : INFINITY);
        force += lock;
        dforce_dl -= lock * k->inv_lock;
    }
    if (l <= 0.0 && v <= 0.0 && force <= 0.0) {
        f[0] = dp; f[1] = 0.0; f[2] = 0.0; f[3] = 0.0;
        j[0] = j_pp;
        for (int i = 1; i < 10; i++)
            j[i] = 0.0;
        return;
    }
    double dz, j_zv, j_zz, j_zp;
    if (v > 0.0 || v < 0.0) {
        double c = k->cos0 * s;
        c = 1.0 - c * c;
        double contact = c > 0.0 ? sqrt(c) * k->inv_sin0 * s : 0.0;
        double speed, direction, dir_factor;
        if (v > 0.0) {
            speed = v; direction = 1.0; dir_factor = k->up_factor;
        } else {
            speed = -v; direction = -1.0; dir_factor = -k->down_factor;
        }
        double base = p > 0.0 ? k->f0 + k->mu * p * contact : k->f0;
        double dbase_dp = p > 0.0 ? k->mu * contact : 0.0;
        double rate, drate_dspeed;
        if (k->rate_gain > 0.0) {
            double rr = pow(speed * k->inv_v_ref, k->rate_exp);
            rate = 1.0 + k->rate_gain * rr;
            drate_dspeed = k->rate_gain * k->rate_exp * rr / speed;
        } else {
            rate = 1.0;
            drate_dspeed = 0.0;
        }
        double level = base * dir_factor * rate;
        double kk = speed * k->inv_delta;
        dz = kk * (level - z);
        j_zv = direction * k->inv_delta * (level - z) + kk * base * dir_factor * drate_dspeed * direction;
        j_zz = -kk;
        j_zp = kk * dbase_dp * dir_factor * rate;
    } else {
        dz = j_zv = j_zz = j_zp = 0.0;
    }
    f[0] = dp; f[1] = v; f[2] = force * inv_mass; f[3] = dz;
    j[0] = j_pp;
    j[1] = -k->k_area * g_area;
    j[2] = -k->k_area * dg_area * v;
    j[3] = k->k_force * slope * g_area * inv_mass;
    j[4] = dforce_dl * inv_mass;
    j[5] = -k->damping * inv_mass;
    j[6] = -inv_mass;
    j[7] = j_zp;
    j[8] = j_zv;
    j[9] = j_zz;
}

/* attempt(x, p, l, v, z, xs, ps, w, h) of build_model: one sub-step; writes (x, p, l, v, z, err). */
static void attempt(const Constants *k, double x, double p, double l, double v, double z, double xs,
                    double ps, double w, double h, double out[6]) {
    double inv_mass = 1e3 / (w / k->gravity + k->m_moving);
    double f[4], J[10];
    jacobian(k, x, p, l, v, z, ps, w, inv_mass, f, J);
    double j_pp = J[0], j_pv = J[1], j_pl = J[2], j_vp = J[3], j_vl = J[4], j_vv = J[5], j_vz = J[6];
    double j_zp = J[7], j_zv = J[8], j_zz = J[9];
    double g = k->gamma * h;
    double dp_inv = 1.0 / (1.0 - g * j_pp);
    double dz_inv = 1.0 / (1.0 - g * j_zz);
    double g_pl = g * j_pl * dp_inv;
    double p1 = (g * g * j_pl + g * j_pv) * dp_inv;
    double zp = dz_inv * g * j_zp;
    double zpv = zp * p1 + dz_inv * g * j_zv;
    double g_vl = g * j_vl, g_vz = g * j_vz;
    double c_p = g * j_vp + g_vz * zp;
    double inv_den = 1.0 / (1.0 - g * j_vv - c_p * p1 - g * g_vl - g_vz * dz_inv * g * j_zv);
    double bp, bl, bv, bz, P0, Z0, kv;
    /* stage 1 */
    bp = g * f[0]; bl = g * f[1]; bv = g * f[2]; bz = g * f[3];
    P0 = bp * dp_inv + g_pl * bl;
    Z0 = bz * dz_inv;
    kv = (bv + c_p * P0 + g_vl * bl + g_vz * Z0) * inv_den;
    double u1p = P0 + p1 * kv, u1l = bl + g * kv, u1v = kv, u1z = Z0 + zp * P0 + zpv * kv;
    /* stage 2 */
    double dx = x - xs;
    double y2v = v + k->a21 * u1v;
    rhs(k, xs + dx * exp(-k->t2 * h / k->tau), p + k->a21 * u1p, l + k->a21 * u1l, y2v, z + k->a21 * u1z, ps, w,
        inv_mass, f);
    bp = g * f[0] + k->c21 * u1p; bl = g * f[1] + k->c21 * u1l; bv = g * f[2] + k->c21 * u1v;
    bz = g * f[3] + k->c21 * u1z;
    P0 = bp * dp_inv + g_pl * bl;
    Z0 = bz * dz_inv;
    kv = (bv + c_p * P0 + g_vl * bl + g_vz * Z0) * inv_den;
    double u2p = P0 + p1 * kv, u2l = bl + g * kv, u2v = kv, u2z = Z0 + zp * P0 + zpv * kv;
    /* stage 3 */
    double y3v = v + k->a31 * u1v + k->a32 * u2v;
    rhs(k, xs + dx * exp(-k->t3 * h / k->tau), p + k->a31 * u1p + k->a32 * u2p, l + k->a31 * u1l + k->a32 * u2l,
        y3v, z + k->a31 * u1z + k->a32 * u2z, ps, w, inv_mass, f);
    bp = g * f[0] + k->c31 * u1p + k->c32 * u2p;
    bl = g * f[1] + k->c31 * u1l + k->c32 * u2l;
    bv = g * f[2] + k->c31 * u1v + k->c32 * u2v;
    bz = g * f[3] + k->c31 * u1z + k->c32 * u2z;
    P0 = bp * dp_inv + g_pl * bl;
    Z0 = bz * dz_inv;
    kv = (bv + c_p * P0 + g_vl * bl + g_vz * Z0) * inv_den;
    double u3p = P0 + p1 * kv, u3l = bl + g * kv, u3v = kv, u3z = Z0 + zp * P0 + zpv * kv;
    /* stage 4 (the end of the sub-step; stiffly accurate, y1 = Y4 + U4) */
    double x1 = xs + dx * exp(-h / k->tau);
    double y4p = p + k->a41 * u1p + k->a42 * u2p + k->a43 * u3p;
    double y4l = l + k->a41 * u1l + k->a42 * u2l + k->a43 * u3l;
    double y4v = v + k->a41 * u1v + k->a42 * u2v + k->a43 * u3v;
    double y4z = z + k->a41 * u1z + k->a42 * u2z + k->a43 * u3z;
    rhs(k, x1, y4p, y4l, y4v, y4z, ps, w, inv_mass, f);
    bp = g * f[0] + k->c41 * u1p + k->c42 * u2p + k->c43 * u3p;
    bl = g * f[1] + k->c41 * u1l + k->c42 * u2l + k->c43 * u3l;
    bv = g * f[2] + k->c41 * u1v + k->c42 * u2v + k->c43 * u3v;
    bz = g * f[3] + k->c41 * u1z + k->c42 * u2z + k->c43 * u3z;
    P0 = bp * dp_inv + g_pl * bl;
    Z0 = bz * dz_inv;
    kv = (bv + c_p * P0 + g_vl * bl + g_vz * Z0) * inv_den;
    double u4p = P0 + p1 * kv, u4l = bl + g * kv, u4v = kv, u4z = Z0 + zp * P0 + zpv * kv;
    /* error estimate, filtered through W^-1 */
    bp = k->e1 * u1p + k->e2 * u2p + k->e3 * u3p + k->e4 * u4p;
    bl = k->e1 * u1l + k->e2 * u2l + k->e3 * u3l + k->e4 * u4l;
    bv = k->e1 * u1v + k->e2 * u2v + k->e3 * u3v + k->e4 * u4v;
    bz = k->e1 * u1z + k->e2 * u2z + k->e3 * u3z + k->e4 * u4z;
    P0 = bp * dp_inv + g_pl * bl;
    Z0 = bz * dz_inv;
    kv = (bv + c_p * P0 + g_vl * bl + g_vz * Z0) * inv_den;
    /* Python's "if e > err: err = e": a NaN never replaces, and a NaN first term stays */
    double err = fabs(P0 + p1 * kv) * k->inv_tol_p, e;
    e = fabs(bl + g * kv) * k->inv_tol_l;
    if (e > err)
        err = e;
    e = fabs(kv) * k->inv_tol_v;
    if (e > err)
        err = e;
    e = fabs(Z0 + zp * P0 + zpv * kv) * k->inv_tol_z;
    if (e > err)
        err = e;
    double v1 = y4v + u4v;
    if (err < k->cross_err && h > k->cross_min_h &&
        ((v > 0.0 && v1 > 0.0 && (y2v < 0.0 || y3v < 0.0 || y4v < 0.0)) ||
         (v < 0.0 && v1 < 0.0 && (y2v > 0.0 || y3v > 0.0 || y4v > 0.0))))
        err = k->cross_err;
    out[0] = x1; out[1] = y4p + u4p; out[2] = y4l + u4l; out[3] = v1; out[4] = y4z + u4z; out[5] = err;
}

/* The first n arguments as doubles; -1 with the exception set if one is not a number. */
static int as_doubles(PyObject *const *args, int n, double *out) {
    for (int i = 0; i < n; i++) {
        out[i] = PyFloat_AsDouble(args[i]);
        if (out[i] == -1.0 && PyErr_Occurred())
            return -1;
    }
    return 0;
}

static PyObject *Model_attempt(ModelObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 9) {
        PyErr_Format(PyExc_TypeError, "attempt() takes 9 arguments (x, p, l, v, z, xs, ps, w, h), got %zd", nargs);
        return NULL;
    }
    double a[9];
    if (as_doubles(args, 9, a) < 0)
        return NULL;
    double out[6];
    attempt(&self->k, a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], a[8], out);
    return Py_BuildValue("(dddddd)", out[0], out[1], out[2], out[3], out[4], out[5]);
}

/* The spool target of a valve command: (u - u_min) / u_span within 0..1. */
static double spool_target(const Constants *k, double u) {
    double xs = (u - k->u_min) / k->u_span;
    return xs < 0.0 ? 0.0 : xs > 1.0 ? 1.0 : xs;
}

/* Both valves open g (0..1) times as far beyond their leak (rosenbrock.build_model's set_gate). */
static void set_gate(ModelObject *self, double g) {
    self->k.kq_open = self->kq_open_full * g;
}

/* FloatingPointError of adaptive_steps when more than forced_max sub-steps of h_min were accepted over
 * their tolerances, with Python's message ("{:.6g}" is PyOS_double_to_string(.., 'g', 6, 0, ..)). */
static PyObject *too_many_substeps(double t, double h_min, long forced) {
    char *ts = PyOS_double_to_string(t, 'g', 6, 0, NULL);
    char *hs = ts == NULL ? NULL : PyOS_double_to_string(h_min, 'g', 6, 0, NULL);
    if (hs != NULL)
        PyErr_Format(PyExc_FloatingPointError, "plant integration failed at t = %s s: too many sub-steps of "
                     "solver.min_substep_s = %s s over their error tolerances in one communication step "
                     "(%ld): stiff/extreme parameters? (a smaller min_substep_s may help)", ts, hs, forced);
    PyMem_Free(ts);
    PyMem_Free(hs);
    return NULL;
}

/* Samples the plant's ports at time t: writes the valve command u [V], supply pressure ps [MPa] and load
 * w [N] (and may set the gate); 0, or -1 with a Python exception set. */
typedef int (*PortsFn)(void *ctx, double t, double *u, double *ps, double *w);

/* advance(...) of build_model: the adaptive sub-steps over one communication step (see there).
 * a: x, p, l, v, z, xs_last, kink_scale, last_ps, u, ps, w, t0, dt; ports NULL: u, ps, w held.
 * out: x, p, l, v, z, xs, kink_scale, last_ps, failed_at (NaN unless the numbers broke down, when the
 * rest is the step's start with the kink scale and supply pressure reached). 0, or -1 with the
 * exception set (a FloatingPointError for too many forced sub-steps, or the ports' error). */
static int advance_core(ModelObject *self, const double a[13], PortsFn ports, void *ctx, double res[9]) {
    const int sample_ports = ports != NULL;
    const Constants *k = &self->k; /* read afresh in every sub-step: the ports may set the gate */
    const double x0 = a[0], p0 = a[1], l0 = a[2], v0 = a[3], z0 = a[4], xs_last = a[5];
    double x = x0, p = p0, l = l0, v = v0, z = z0, kink_scale = a[6], last_ps = a[7];
    double u = a[8], ps = a[9], w = a[10];
    const double t0 = a[11], dt = a[12];
    double xs = sample_ports ? xs_last : spool_target(k, u);
    double done = 0.0, left = dt, h_try = 0.0, kink_root = 1.0, h, out[6];
    int first = 1, sampled = 0, retry = 0, last;
    long forced = 0; /* sub-steps accepted at the shortest sub-step although over their tolerances */
    unsigned long attempts = 0; /* a step of an hour at a 10-us sub-step takes minutes: Ctrl-C must stop it */
    double forced_max = dt / k->h_max;
    if (forced_max < k->forced_max)
        forced_max = k->forced_max;
    for (;;) {
        if (sample_ports && !sampled) {
            if (ports(ctx, t0 + done, &u, &ps, &w) < 0)
                return -1;
            xs = spool_target(k, u);
            sampled = 1;
        }
        if (first && !retry) {
            double kink = xs - xs_last;
            kink = kink > k->kink_floor ? kink : -kink > k->kink_floor ? -kink : k->kink_floor;
            kink_root = pow(kink, 1.0 / 3.0);
            h_try = kink_scale / kink_root;
        }
        if (h_try > k->h_max)
            h_try = k->h_max;
        if (!(h_try >= k->h_min)) /* never propose less than the shortest sub-step (nor NaN) */
            h_try = k->h_min;
        if (left <= (retry ? h_try : k->stretch * h_try)) {
            h = left;
            last = 1;
        } else if (left < 2.0 * h_try) {
            h = 0.5 * left;
            last = 0;
        } else {
            h = h_try;
            last = 0;
        }
        if ((++attempts & 0xFFFF) == 0 && PyErr_CheckSignals() < 0)
            return -1; /* the caller keeps the step's start */
        attempt(k, x, p, l, v, z, xs, ps, w, h, out);
        double err = out[5];
        if (err <= 1.0 || h <= k->h_min) {
            if (!(err < INFINITY)) { /* the state of the step's start, and the time it broke down */
                const double broke[9] = {x0, p0, l0, v0, z0, xs_last, kink_scale, last_ps, t0 + done};
                memcpy(res, broke, sizeof broke);
                return 0;
            }
            if (err > 1.0) { /* accepted only for being the shortest sub-step */
                forced += 1;
                self->forced_total += 1;
                if ((double)forced > forced_max) {
                    too_many_substeps(t0 + done, k->h_min, forced);
                    return -1;
                }
            }
            x = out[0];
            p = out[1];
            l = out[2];
            v = out[3];
            z = out[4];
            if (l < 0.0) {
                l = 0.0;
                if (v < 0.0)
                    v = 0.0;
            }
            double fac = err > k->err_floor ? k->safety * pow(err, -1.0 / 3.0) : k->growth;
            if (fac > k->growth)
                fac = k->growth;
            double h_next = h * fac;
            if (first) {
                if (!last || fac < 1.0 || h_next * kink_root > kink_scale)
                    kink_scale = h_next * kink_root;
                first = 0;
            }
            last_ps = ps;
            if (last)
                break;
            done += h;
            left = dt - done;
            h_try = h_next;
            sampled = retry = 0;
        } else {
            double fac = k->safety * pow(err, -1.0 / 3.0);
            h_try = h * (fac > k->shrink ? fac : k->shrink);
            retry = 1;
        }
    }
    const double ended[9] = {x, p, l, v, z, xs, kink_scale, last_ps, (double)NAN};
    memcpy(res, ended, sizeof ended);
    return 0;
}

/* The ports of advance() from a Python callable ports(t) -> (u, ps, w). */
static int python_ports(void *ctx, double t, double *u, double *ps, double *w) {
    PyObject *tt = PyFloat_FromDouble(t);
    if (tt == NULL)
        return -1;
    PyObject *r = PyObject_CallOneArg((PyObject *)ctx, tt);
    Py_DECREF(tt);
    if (r == NULL)
        return -1;
    if (!PyTuple_Check(r) || PyTuple_GET_SIZE(r) != 3) {
        Py_DECREF(r);
        PyErr_SetString(PyExc_TypeError, "advance(): ports(t) must return a tuple (u, ps, w)");
        return -1;
    }
    *u = PyFloat_AsDouble(PyTuple_GET_ITEM(r, 0));
    *ps = PyFloat_AsDouble(PyTuple_GET_ITEM(r, 1));
    *w = PyFloat_AsDouble(PyTuple_GET_ITEM(r, 2));
    Py_DECREF(r);
    return PyErr_Occurred() ? -1 : 0;
}

static PyObject *Model_advance(ModelObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 14) {
        PyErr_Format(PyExc_TypeError, "advance() takes 14 arguments (x, p, l, v, z, xs_last, kink_scale, "
                     "last_ps, u, ps, w, t0, dt, ports), got %zd", nargs);
        return NULL;
    }
    double a[13], r[9];
    if (as_doubles(args, 13, a) < 0)
        return NULL;
    PyObject *ports = args[13];
    if (advance_core(self, a, ports == Py_None ? NULL : python_ports, ports, r) < 0)
        return NULL;
    return Py_BuildValue("(ddddddddd)", r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8]);
}

/* ---------------------------------------------------------------------------------------------------
 * run(...): Plant.step_many for a plant whose effects all come from effect_library.py, compiled.
 *
 * The Python loop (plant.py: step_many, _integrate, _advance, _ports, _readings, and the effects'
 * breakpoints, held and port hooks) is the definition; this is that loop, call for call and operation
 * for operation, with the library effects' arithmetic inlined, so that it gives the same bits. Only
 * for noise-free sensors (no random draws) and the library's effects in their fixed order
 * (plant.py decides; compiled_run.py packs the arguments). tests/test_compiled_run.py checks the bits.
 */

typedef struct {
    ModelObject *model;
    double u_cmd, supply, load; /* the plant's port signals before the effects */
    double gate;                /* the valve gate last set */
    int acts_on_ports;
    /* transport_delay: the command's change instants and values, in order (never empty) */
    int has_delay;
    double delay_s, *times, *values;
    Py_ssize_t n_hist, cap_hist;
    /* input_map: out_at_0_v, knot1_in_v, knot1_out_v, knot2_in_v, knot2_out_v, out_at_10_v */
    int has_map;
    double map[6];
    /* valve_dead_zone */
    int has_dz;
    double dz_lo, dz_hi;
    /* supply_pressure_variation */
    int has_sag;
    double sag, start, end, ramp, back, ripple, ripple_period, corners[4];
    int n_corners;
    /* load_mismatch */
    int has_load;
    double extra_n;
    /* backlash, sensor_drift */
    int has_backlash, has_drift;
    double half_play, slider, drift_offset, drift_rate;
    /* the breakpoints of the current step */
    double *cuts;
    Py_ssize_t n_cuts, cap_cuts;
} Rig;

/* bisect.bisect_right(a[:n], x) */
static Py_ssize_t bisect_right(const double *a, Py_ssize_t n, double x) {
    Py_ssize_t lo = 0, hi = n;
    while (lo < hi) {
        Py_ssize_t mid = (lo + hi) / 2;
        if (x < a[mid])
            hi = mid;
        else
            lo = mid + 1;
    }
    return lo;
}

static int grow(double **a, double **b, Py_ssize_t *cap, Py_ssize_t need) {
    if (need <= *cap)
        return 0;
    Py_ssize_t cap2 = 2 * need + 16;
    double *a2 = PyMem_Realloc(*a, cap2 * sizeof(double));
    if (a2 == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    *a = a2;
    if (b != NULL) {
        double *b2 = PyMem_Realloc(*b, cap2 * sizeof(double));
        if (b2 == NULL) {
            PyErr_NoMemory();
            return -1;
        }
        *b = b2;
    }
    *cap = cap2;
    return 0;
}

/* TransportDelay._record_change */
static int delay_record_change(Rig *r, double t, double u) {
    if (t >= r->times[r->n_hist - 1]) {
        if (grow(&r->times, &r->values, &r->cap_hist, r->n_hist + 1) < 0)
            return -1;
        r->times[r->n_hist] = t;
        r->values[r->n_hist] = u;
        r->n_hist += 1;
        Py_ssize_t cut = bisect_right(r->times, r->n_hist, t - r->delay_s) - 1;
        if (cut > 8) {
            memmove(r->times, r->times + cut, (r->n_hist - cut) * sizeof(double));
            memmove(r->values, r->values + cut, (r->n_hist - cut) * sizeof(double));
            r->n_hist -= cut;
        }
    }
    return 0;
}

static int add_cut(Rig *r, double t) {
    if (grow(&r->cuts, NULL, &r->cap_cuts, r->n_cuts + 1) < 0)
        return -1;
    r->cuts[r->n_cuts++] = t;
    return 0;
}

/* effect_library._SAME_INSTANT_S: instants closer than this [s] are one */
#define SAME_INSTANT_S 1e-12

/* TransportDelay.breakpoints, appended to the step's cuts */
static int delay_breakpoints(Rig *r, double t0, double t1, double u) {
    if (u != r->values[r->n_hist - 1] && delay_record_change(r, t0, u) < 0)
        return -1;
    const double d = r->delay_s;
    Py_ssize_t first = r->n_cuts;
    for (Py_ssize_t j = r->n_hist - 1; j >= 0; j--) {
        double seen = r->times[j] + d;
        if (seen <= t0 + SAME_INSTANT_S)
            break;
        if (seen < t1 - SAME_INSTANT_S && add_cut(r, seen) < 0)
            return -1;
    }
    for (Py_ssize_t i = first, j = r->n_cuts - 1; i < j; i++, j--) { /* out.reverse() */
        double s = r->cuts[i];
        r->cuts[i] = r->cuts[j];
        r->cuts[j] = s;
    }
    return 0;
}

/* TransportDelay.valve_command */
static int delay_command(Rig *r, double t, double *u) {
    if (*u != r->values[r->n_hist - 1] && delay_record_change(r, t, *u) < 0)
        return -1;
    Py_ssize_t i = bisect_right(r->times, r->n_hist, t - r->delay_s + SAME_INSTANT_S) - 1;
    *u = r->values[i >= 0 ? i : 0];
    return 0;
}

/* effect_library.input_map_v */
static double input_map(const double m[6], double u) {
    double x0, y0, x1, y1;
    if (u < m[1]) {
        x0 = 0.0; y0 = m[0]; x1 = m[1]; y1 = m[2];
    } else if (u < m[3]) {
        x0 = m[1]; y0 = m[2]; x1 = m[3]; y1 = m[4];
    } else {
        x0 = m[3]; y0 = m[4]; x1 = 10.0; y1 = m[5];
    }
    double y = y0 + (y1 - y0) * (u - x0) / (x1 - x0);
    return y < 0.0 ? 0.0 : y > 10.0 ? 10.0 : y;
}

/* SupplyPressureVariation.sag_mpa (Python's min(a, b) is b only if b < a; max(a, b) b only if b > a) */
static double sag_mpa(const Rig *r, double t) {
    if (r->sag == 0.0 || t <= r->start)
        return 0.0;
    double up = 1.0, down;
    if (r->ramp != 0.0) {
        double f = (t - r->start) / r->ramp;
        up = f < 1.0 ? f : 1.0;
    }
    if (t <= r->end)
        down = 1.0;
    else if (r->back == 0.0)
        down = 0.0;
    else {
        double f = 1.0 - (t - r->end) / r->back;
        down = f > 0.0 ? f : 0.0;
    }
    return r->sag * (down < up ? down : up);
}

/* SupplyPressureVariation.held */
static int sag_held(const Rig *r, double t0, double t1) {
    if (r->ripple != 0.0)
        return 0;
    if (r->sag == 0.0 || t1 <= r->start)
        return 1;
    if (t0 <= r->start)
        return 0;
    if (t1 <= r->end)
        return r->ramp == 0.0 || (t0 - r->start) / r->ramp >= 1.0;
    return t0 > r->end && (r->back == 0.0 || 1.0 - (t0 - r->end) / r->back <= 0.0);
}

/* Plant._ports with the library effects in their order (effect_library.effects_from_params) */
static int rig_ports(void *ctx, double t, double *u_out, double *ps_out, double *w_out) {
    Rig *r = (Rig *)ctx;
    double u = r->u_cmd, ps = r->supply, w = r->load, gate = 1.0;
    if (r->has_delay && delay_command(r, t, &u) < 0)
        return -1;
    if (r->has_map)
        u = input_map(r->map, u);
    if (r->has_dz)
        gate *= (r->dz_lo < u && u < r->dz_hi) ? 0.0 : 1.0;
    if (r->has_sag) {
        ps = ps - sag_mpa(r, t);
        if (r->ripple != 0.0)
            ps += r->ripple * sin(2.0 * Py_MATH_PI * t / r->ripple_period);
        ps = ps > 0.0 ? ps : 0.0;
    }
    if (r->has_load) {
        w = w + r->extra_n;
        w = w > 0.0 ? w : 0.0;
    }
    if (gate != r->gate) {
        r->gate = gate;
        set_gate(r->model, gate);
    }
    *u_out = u;
    *ps_out = ps;
    *w_out = w;
    return 0;
}

/* The plant's integration state between stretches. */
typedef struct {
    double s[5], xs_last, kink_scale, last_ps;
} Track;

/* How a stretch ended. */
enum { STRETCH_OK = 0, STRETCH_BROKE = 1, STRETCH_ERROR = -1 };

/* Plant._advance over [t0, t0 + dt]; on STRETCH_BROKE *failed_at and *at (the stretch's start state)
 * say where, as the Python error message needs them. */
static int rig_stretch(Rig *r, Track *tr, double t0, double dt, double *failed_at, double at[5]) {
    int sample = r->acts_on_ports || r->gate != 1.0;
    double u = r->u_cmd, ps = r->supply, w = r->load;
    if (sample && (!r->has_sag || sag_held(r, t0, t0 + dt))) { /* every other library effect holds */
        if (rig_ports(r, t0, &u, &ps, &w) < 0)
            return STRETCH_ERROR;
        sample = 0;
    }
    const double a[13] = {tr->s[0], tr->s[1], tr->s[2], tr->s[3], tr->s[4], tr->xs_last, tr->kink_scale,
                          tr->last_ps, u, ps, w, t0, dt};
    double res[9];
    if (advance_core(r->model, a, sample ? rig_ports : NULL, r, res) < 0)
        return STRETCH_ERROR;
    tr->kink_scale = res[6];
    tr->last_ps = res[7];
    if (res[8] == res[8]) {
        *failed_at = res[8];
        memcpy(at, tr->s, sizeof tr->s);
        return STRETCH_BROKE;
    }
    memcpy(tr->s, res, sizeof tr->s);
    tr->xs_last = res[5];
    return STRETCH_OK;
}

static int compare_doubles(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Plant._integrate (the step's breakpoints, then a stretch between each two) */
static int rig_step(Rig *r, Track *tr, double t0, double dt, double *failed_at, double at[5]) {
    const double t1 = t0 + dt;
    r->n_cuts = 0;
    if (r->has_delay && delay_breakpoints(r, t0, t1, r->u_cmd) < 0)
        return STRETCH_ERROR;
    for (int j = 0; j < r->n_corners; j++)
        if (t0 < r->corners[j] && r->corners[j] < t1 && add_cut(r, r->corners[j]) < 0)
            return STRETCH_ERROR;
    if (r->n_cuts > 1) { /* sorted(set(cuts)) */
        qsort(r->cuts, r->n_cuts, sizeof(double), compare_doubles);
        Py_ssize_t m = 1;
        for (Py_ssize_t i = 1; i < r->n_cuts; i++)
            if (r->cuts[i] != r->cuts[m - 1])
                r->cuts[m++] = r->cuts[i];
        r->n_cuts = m;
    }
    if (r->n_cuts == 0)
        return rig_stretch(r, tr, t0, dt, failed_at, at);
    const Track saved = *tr;
    const double saved_gate = r->gate;
    double ta = t0;
    for (Py_ssize_t i = 0; i <= r->n_cuts; i++) {
        double tb = i < r->n_cuts ? r->cuts[i] : t1;
        int rc = rig_stretch(r, tr, ta, tb - ta, failed_at, at);
        if (rc != STRETCH_OK) { /* the step's start again, as Plant._integrate restores it */
            *tr = saved;
            r->gate = saved_gate;
            set_gate(r->model, saved_gate);
            return rc;
        }
        ta = tb;
    }
    return STRETCH_OK;
}

/* sensors.quantise: Python's round() gives an int, so a rounded -0.0 becomes +0 */
static double quantise(double value, double resolution) {
    if (resolution <= 0.0)
        return value;
    double n = nearbyint(value / resolution);
    return (n == 0.0 ? 0.0 : n) * resolution;
}

static int as_buffer(PyObject *obj, Py_buffer *view, int writable, const char *name) {
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0)) < 0)
        return -1;
    if (view->ndim != 1 || view->itemsize != sizeof(double) || view->format == NULL || strcmp(view->format, "d") != 0) {
        PyBuffer_Release(view);
        PyErr_Format(PyExc_TypeError, "run(): %s must be a one-dimensional float64 array", name);
        return -1;
    }
    return 0;
}

/* Reads the tuple `spec` (compiled_run.py) into the rig; 0 or -1. */
static int rig_from_spec(Rig *r, PyObject *spec) {
    if (!PyTuple_Check(spec) || PyTuple_GET_SIZE(spec) != 7) {
        PyErr_SetString(PyExc_TypeError, "run(): spec must be a tuple of 7 (one per library effect)");
        return -1;
    }
    double v[11];
    static const Py_ssize_t sizes[7] = {1, 6, 2, 11, 1, 2, 2};
    for (Py_ssize_t e = 0; e < 7; e++) {
        PyObject *item = PyTuple_GET_ITEM(spec, e);
        if (item == Py_None)
            continue;
        if (!PyTuple_Check(item) || PyTuple_GET_SIZE(item) != sizes[e]) {
            PyErr_Format(PyExc_TypeError, "run(): spec[%zd] must be None or a tuple of %zd numbers", e, sizes[e]);
            return -1;
        }
        for (Py_ssize_t i = 0; i < sizes[e]; i++) {
            v[i] = PyFloat_AsDouble(PyTuple_GET_ITEM(item, i));
            if (v[i] == -1.0 && PyErr_Occurred())
                return -1;
        }
        switch (e) {
        case 0: r->has_delay = 1; r->delay_s = v[0]; break;
        case 1: r->has_map = 1; memcpy(r->map, v, sizeof r->map); break;
        case 2: r->has_dz = 1; r->dz_lo = v[0]; r->dz_hi = v[1]; break;
        case 3:
            r->has_sag = 1; r->sag = v[0]; r->start = v[1]; r->end = v[2]; r->ramp = v[3]; r->back = v[4];
            r->ripple = v[5]; r->ripple_period = v[6];
            r->n_corners = 4; /* SupplyPressureVariation._corners, NaN where it has none */
            memcpy(r->corners, v + 7, sizeof r->corners);
            break;
        case 4: r->has_load = 1; r->extra_n = v[0]; break;
        case 5: r->has_backlash = 1; r->half_play = v[0]; r->slider = v[1]; break;
        case 6: r->has_drift = 1; r->drift_offset = v[0]; r->drift_rate = v[1]; break;
        }
    }
    r->acts_on_ports = r->has_delay || r->has_map || r->has_dz || r->has_sag || r->has_load;
    return 0;
}

static int read_history(Rig *r, PyObject *times, PyObject *values) {
    if (!PyList_Check(times) || !PyList_Check(values) || PyList_GET_SIZE(times) != PyList_GET_SIZE(values) ||
        PyList_GET_SIZE(times) == 0) {
        PyErr_SetString(PyExc_TypeError, "run(): the delay's history must be two non-empty lists of one length");
        return -1;
    }
    Py_ssize_t n = PyList_GET_SIZE(times);
    if (grow(&r->times, &r->values, &r->cap_hist, n + 64) < 0)
        return -1;
    for (Py_ssize_t i = 0; i < n; i++) {
        r->times[i] = PyFloat_AsDouble(PyList_GET_ITEM(times, i));
        r->values[i] = PyFloat_AsDouble(PyList_GET_ITEM(values, i));
    }
    r->n_hist = n;
    return PyErr_Occurred() ? -1 : 0;
}

static PyObject *list_of(const double *a, Py_ssize_t n) {
    PyObject *out = PyList_New(n);
    if (out == NULL)
        return NULL;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *f = PyFloat_FromDouble(a[i]);
        if (f == NULL) {
            Py_DECREF(out);
            return NULL;
        }
        PyList_SET_ITEM(out, i, f);
    }
    return out;
}

/* run(u, loads, l_out, p_out, dt, plant, sensor, spec, delay_times, delay_values) -> (done, plant, gate,
 * delay_times, delay_values, slider, failure): see compiled_run.py, which is its only caller. */
static PyObject *Model_run(ModelObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 10) {
        PyErr_Format(PyExc_TypeError, "run() takes 10 arguments, got %zd", nargs);
        return NULL;
    }
    Rig r = {0};
    r.model = self;
    Py_buffer ub = {0}, wb = {0}, lb = {0}, pb = {0};
    int have_w = args[1] != Py_None;
    PyObject *result = NULL, *failure = NULL;
    double plant[13], sensor[3];
    double gate_in = NAN; /* the gate before the run, once read */
    if (as_buffer(args[0], &ub, 0, "u") < 0)
        return NULL;
    if ((have_w && as_buffer(args[1], &wb, 0, "loads") < 0) || as_buffer(args[2], &lb, 1, "l_out") < 0)
        goto done;
    if (as_buffer(args[3], &pb, 1, "p_out") < 0)
        goto done;
    const Py_ssize_t n = ub.shape[0];
    if ((have_w && wb.shape[0] != n) || lb.shape[0] != n || pb.shape[0] != n) {
        PyErr_SetString(PyExc_ValueError, "run(): u, loads, l_out and p_out must have one length");
        goto done;
    }
    double dt = PyFloat_AsDouble(args[4]);
    if (dt == -1.0 && PyErr_Occurred())
        goto done;
    PyObject *pv = PySequence_Fast(args[5], "run(): plant must be a sequence of 13 numbers");
    if (pv == NULL)
        goto done;
    int bad = PySequence_Fast_GET_SIZE(pv) != 13;
    for (Py_ssize_t i = 0; !bad && i < 13; i++)
        plant[i] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(pv, i));
    Py_DECREF(pv);
    if (bad || PyErr_Occurred()) {
        if (!PyErr_Occurred())
            PyErr_SetString(PyExc_TypeError, "run(): plant must be a sequence of 13 numbers");
        goto done;
    }
    if (!PyArg_ParseTuple(args[6], "ddd", &sensor[0], &sensor[1], &sensor[2]) || rig_from_spec(&r, args[7]) < 0)
        goto done;
    if (r.has_delay && read_history(&r, args[8], args[9]) < 0)
        goto done;
    /* plant: t_s, x, p, l, v, z, xs_last, kink_scale, last_ps, gate, u_v, load_n, supply_pressure_mpa */
    double t = plant[0];
    Track tr = {{plant[1], plant[2], plant[3], plant[4], plant[5]}, plant[6], plant[7], plant[8]};
    r.gate = gate_in = plant[9];
    r.u_cmd = plant[10];
    r.load = plant[11];
    r.supply = plant[12];
    const double *u = ub.buf, *w = have_w ? wb.buf : NULL;
    double *l_out = lb.buf, *p_out = pb.buf;
    Py_ssize_t i;
    for (i = 0; i < n; i++) {
        if ((i & 4095) == 4095 && PyErr_CheckSignals() < 0)
            goto error;
        if (w != NULL && w[i] != r.load)
            r.load = w[i];
        r.u_cmd = u[i];
        double failed_at, at[5];
        int rc = rig_step(&r, &tr, t, dt, &failed_at, at);
        if (rc == STRETCH_BROKE) {
            failure = Py_BuildValue("(sd(ddddd))", "broke", failed_at, at[0], at[1], at[2], at[3], at[4]);
            break;
        }
        if (rc == STRETCH_ERROR) {
            if (!PyErr_ExceptionMatches(PyExc_FloatingPointError))
                goto error;
            PyObject *type, *value, *tb;
            PyErr_Fetch(&type, &value, &tb);
            PyErr_NormalizeException(&type, &value, &tb);
            Py_XDECREF(type);
            Py_XDECREF(tb);
            failure = Py_BuildValue("(sN)", "raised", value);
            break;
        }
        t = t + dt;
        /* Plant._readings: the measurement effects in their order, then the sensors */
        double l_seen = tr.s[2];
        if (r.has_backlash) {
            if (l_seen - r.slider > r.half_play)
                r.slider = l_seen - r.half_play;
            else if (r.slider - l_seen > r.half_play)
                r.slider = l_seen + r.half_play;
            l_seen = r.slider;
        }
        if (r.has_drift)
            l_seen = l_seen + r.drift_offset + r.drift_rate * t;
        double p_seen = quantise(tr.s[1], sensor[1]);
        p_seen = 0.0 > p_seen ? 0.0 : p_seen;
        l_out[i] = quantise(l_seen, sensor[0]);
        p_out[i] = sensor[2] < p_seen ? sensor[2] : p_seen;
    }
    if (failure == NULL && PyErr_Occurred())
        goto error;
    PyObject *times = r.has_delay ? list_of(r.times, r.n_hist) : Py_NewRef(Py_None);
    PyObject *values = r.has_delay ? list_of(r.values, r.n_hist) : Py_NewRef(Py_None);
    if (times != NULL && values != NULL)
        result = Py_BuildValue("(n(ddddddddddd)dOOdO)", i, t, tr.s[0], tr.s[1], tr.s[2], tr.s[3], tr.s[4],
                               tr.xs_last, tr.kink_scale, tr.last_ps, r.u_cmd, r.load, r.gate, times, values,
                               r.slider, failure != NULL ? failure : Py_None);
    Py_XDECREF(times);
    Py_XDECREF(values);
    goto done;
error: /* the plant as it was: its Python side is untouched, and the gate goes back */
    if (gate_in == gate_in)
        set_gate(self, gate_in);
done:
    Py_XDECREF(failure);
    PyMem_Free(r.times);
    PyMem_Free(r.values);
    PyMem_Free(r.cuts);
    if (ub.obj != NULL)
        PyBuffer_Release(&ub);
    if (wb.obj != NULL)
        PyBuffer_Release(&wb);
    if (lb.obj != NULL)
        PyBuffer_Release(&lb);
    if (pb.obj != NULL)
        PyBuffer_Release(&pb);
    return result;
}

static PyObject *Model_set_gate(ModelObject *self, PyObject *arg) {
    double g = PyFloat_AsDouble(arg);
    if (g == -1.0 && PyErr_Occurred())
        return NULL;
    set_gate(self, g);
    Py_RETURN_NONE;
}

static int Model_init(ModelObject *self, PyObject *args, PyObject *kwds) {
    PyObject *values;
    if (!PyArg_ParseTuple(args, "O:Model", &values))
        return -1;
    PyObject *seq = PySequence_Fast(values, "Model() takes a sequence of the constants named in NAMES");
    if (seq == NULL)
        return -1;
    if (PySequence_Fast_GET_SIZE(seq) != N_CONSTANTS) {
        PyErr_Format(PyExc_ValueError, "Model() takes %d constants (NAMES), got %zd", N_CONSTANTS,
                     PySequence_Fast_GET_SIZE(seq));
        Py_DECREF(seq);
        return -1;
    }
    double *dst = (double *)&self->k;
    for (Py_ssize_t i = 0; i < N_CONSTANTS; i++) {
        double d = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(seq, i));
        if (d == -1.0 && PyErr_Occurred()) {
            Py_DECREF(seq);
            return -1;
        }
        dst[i] = d;
    }
    Py_DECREF(seq);
    self->kq_open_full = self->k.kq_open;
    return 0;
}

static PyMethodDef Model_methods[] = {
    {"attempt", (PyCFunction)(void (*)(void))Model_attempt, METH_FASTCALL,
     "attempt(x, p, l, v, z, xs, ps, w, h) -> (x, p, l, v, z, err): one ROS34PW2 sub-step (rosenbrock.build_model)."},
    {"advance", (PyCFunction)(void (*)(void))Model_advance, METH_FASTCALL,
     "advance(x, p, l, v, z, xs_last, kink_scale, last_ps, u, ps, w, t0, dt, ports) -> (x, p, l, v, z, xs, "
     "kink_scale, last_ps, failed_at): the sub-steps of one communication step (rosenbrock.build_model)."},
    {"run", (PyCFunction)(void (*)(void))Model_run, METH_FASTCALL,
     "run(u, loads, l_out, p_out, dt, plant, sensor, spec, delay_times, delay_values) -> (done, plant, gate, "
     "delay_times, delay_values, slider, failure): Plant.step_many with the library effects (compiled_run.py)."},
    {"set_gate", (PyCFunction)Model_set_gate, METH_O,
     "set_gate(g): both valves open g (0..1) times as far beyond their leak from now on."},
    {NULL, NULL, 0, NULL},
};

static PyObject *Model_forced_substeps(ModelObject *self, void *closure) {
    (void)closure;
    return PyLong_FromLongLong(self->forced_total);
}

static PyGetSetDef Model_getset[] = {
    {"forced_substeps", (getter)Model_forced_substeps, NULL,
     "Sub-steps of solver.min_substep_s accepted over their error tolerances since construction "
     "(rosenbrock.forced_substeps).", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject ModelType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "fmu_plant._ros34pw2.Model",
    .tp_basicsize = sizeof(ModelObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "Model(values): the constants of one plant, in the order of NAMES.",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Model_init,
    .tp_methods = Model_methods,
    .tp_getset = Model_getset,
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_ros34pw2",
    "The ROS34PW2 sub-step of fmu_plant.rosenbrock, compiled (bit for bit the same arithmetic).", -1, NULL,
};

PyMODINIT_FUNC PyInit__ros34pw2(void) {
    /* the struct is read as an array of doubles in Model_init */
    Py_BUILD_ASSERT(sizeof(Constants) == N_CONSTANTS * sizeof(double));
    if (PyType_Ready(&ModelType) < 0)
        return NULL;
    PyObject *m = PyModule_Create(&module);
    if (m == NULL)
        return NULL;
    PyObject *names = PyTuple_New(N_CONSTANTS);
    if (names == NULL) {
        Py_DECREF(m);
        return NULL;
    }
    for (Py_ssize_t i = 0; i < N_CONSTANTS; i++) {
        PyObject *s = PyUnicode_FromString(constant_names[i]);
        if (s == NULL) {
            Py_DECREF(names);
            Py_DECREF(m);
            return NULL;
        }
        PyTuple_SET_ITEM(names, i, s);
    }
    Py_INCREF(&ModelType);
    if (PyModule_AddObject(m, "NAMES", names) < 0 || PyModule_AddObject(m, "Model", (PyObject *)&ModelType) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}

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

/* advance(...) of build_model: the adaptive sub-steps over one communication step (see there). */
static PyObject *Model_advance(ModelObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 14) {
        PyErr_Format(PyExc_TypeError, "advance() takes 14 arguments (x, p, l, v, z, xs_last, kink_scale, "
                     "last_ps, u, ps, w, t0, dt, ports), got %zd", nargs);
        return NULL;
    }
    double a[13];
    if (as_doubles(args, 13, a) < 0)
        return NULL;
    PyObject *ports = args[13];
    const int sample_ports = ports != Py_None;
    const Constants *k = &self->k; /* read afresh in every sub-step: the ports may set the gate */
    const double x0 = a[0], p0 = a[1], l0 = a[2], v0 = a[3], z0 = a[4], xs_last = a[5];
    double x = x0, p = p0, l = l0, v = v0, z = z0, kink_scale = a[6], last_ps = a[7];
    double u = a[8], ps = a[9], w = a[10];
    const double t0 = a[11], dt = a[12];
    double xs = sample_ports ? xs_last : spool_target(k, u);
    double done = 0.0, left = dt, h_try = 0.0, kink_root = 1.0, h, out[6];
    int first = 1, sampled = 0, retry = 0, last;
    long forced = 0; /* sub-steps accepted at the shortest sub-step although over their tolerances */
    double forced_max = dt / k->h_max;
    if (forced_max < k->forced_max)
        forced_max = k->forced_max;
    for (;;) {
        if (sample_ports && !sampled) {
            PyObject *t = PyFloat_FromDouble(t0 + done);
            if (t == NULL)
                return NULL;
            PyObject *r = PyObject_CallOneArg(ports, t);
            Py_DECREF(t);
            if (r == NULL)
                return NULL;
            if (!PyTuple_Check(r) || PyTuple_GET_SIZE(r) != 3) {
                Py_DECREF(r);
                PyErr_SetString(PyExc_TypeError, "advance(): ports(t) must return a tuple (u, ps, w)");
                return NULL;
            }
            u = PyFloat_AsDouble(PyTuple_GET_ITEM(r, 0));
            ps = PyFloat_AsDouble(PyTuple_GET_ITEM(r, 1));
            w = PyFloat_AsDouble(PyTuple_GET_ITEM(r, 2));
            Py_DECREF(r);
            if (PyErr_Occurred())
                return NULL;
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
        attempt(k, x, p, l, v, z, xs, ps, w, h, out);
        double err = out[5];
        if (err <= 1.0 || h <= k->h_min) {
            if (!(err < INFINITY)) /* the state of the step's start, and the time it broke down */
                return Py_BuildValue("(ddddddddd)", x0, p0, l0, v0, z0, xs_last, kink_scale, last_ps, t0 + done);
            if (err > 1.0) { /* accepted only for being the shortest sub-step */
                forced += 1;
                if ((double)forced > forced_max)
                    return too_many_substeps(t0 + done, k->h_min, forced);
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
    return Py_BuildValue("(ddddddddd)", x, p, l, v, z, xs, kink_scale, last_ps, (double)NAN);
}

static PyObject *Model_set_gate(ModelObject *self, PyObject *arg) {
    double g = PyFloat_AsDouble(arg);
    if (g == -1.0 && PyErr_Occurred())
        return NULL;
    self->k.kq_open = self->kq_open_full * g;
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
    {"set_gate", (PyCFunction)Model_set_gate, METH_O,
     "set_gate(g): both valves open g (0..1) times as far beyond their leak from now on."},
    {NULL, NULL, 0, NULL},
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

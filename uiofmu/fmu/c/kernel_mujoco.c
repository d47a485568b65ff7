/* uiofmu: the MuJoCo plant kernel, the model code of uiofmu's C MuJoCo plant FMUs.
 *
 * It plugs into the shared FMI 2.0 plumbing (fmi2_plumbing.c) through UIOFMU_KERNEL_MUJOCO; the
 * plant's numbers come from design_data.c (UIOFMU_MUJOCO, generated), the physics from MuJoCo
 * (libmujoco, shipped next to the FMU's binary and found through its $ORIGIN run path), the model
 * from the MJCF in the FMU's resources/ (UIOFMU_MJCF_FILE), loaded with mj_loadXML from the
 * resource location the importer passes to fmi2Instantiate (a file:// URI, percent-encoded, or a
 * plain absolute path). The step semantics are those of the reference runtime
 * (uiofmu/runtime/mujoco_runtime.py), call for call, so the two agree to the last bit:
 *
 *   outputs:          x = [qpos of the joints, qvel of the joints], y = C x (no input feeds through)
 *   initialisation:   the physical parameters written into the model, then mj_resetData, qpos and
 *                     qvel of the joints at the parameter x0, mj_forward
 *   fmi2DoStep(t, h): ctrl of the u and d actuators at the inputs (held over the step);
 *                     floor(h/dt + 1e-9) calls of mj_step at the fixed substep dt, then one of the
 *                     rest when it is above 1e-9 dt; mjData.time is then its value before the
 *                     step plus h
 *
 * A step of more than max_substeps substeps is refused with fmi2Discard and the reference's log
 * line (nothing changes); non-finite inputs with fmi2Error and a log line naming the input. MuJoCo
 * itself resets a simulation whose state, acceleration or controls blow up, as it does under the
 * reference; a step during which MuJoCo warned returns fmi2OK with one fmi2Warning line per kind of
 * warning (mju_warningText, and how many times). MuJoCo's default log handler also prints them and
 * appends them to MUJOCO_LOG.TXT in the working directory, as it does under the reference.
 *
 * fmi2Instantiate refuses (NULL, one log line) a resource location it cannot read, an MJCF MuJoCo
 * cannot load, a libmujoco of another version than the one the FMU was built with, and a model
 * whose sizes differ from those compiled in (an edited MJCF): every index compiled in is then
 * checked against the model before it is used.
 *
 * FMU state: after the plumbing's header (magic, layout, size, GUID, the shape words nq, nv, na,
 * nu and the count of doubles), 2 + n + P + m + q + nq + nv + na + nu doubles, written and read
 * with memcpy:
 *
 *   phase, time, x0[n], params[P], u[m], d[q], qpos[nq], qvel[nv], act[na], ctrl[nu]
 *
 * the reference runtime's state (mjData's qpos, qvel, act, ctrl and time; the parameters as the
 * ports hold them). Checked before any of it is used: phase one of 0 to 3, time finite and >= 0,
 * x0 and the physical parameters finite (fmi2ExitInitializationMode refuses others), qpos, qvel,
 * act and ctrl finite; u and d any value (inputs that fmi2SetReal takes and fmi2DoStep refuses).
 * A refused state changes nothing (fmi2Error and a log line naming the first bad number). A state
 * taken is restored as the reference restores it: the parameters written into the model, mjData's
 * fields set, then mj_forward.
 *
 * MuJoCo's global error and warning handlers are left as they are: the process may hold another
 * user of the same libmujoco (a Python host that imported mujoco), whose handlers they are.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <mujoco/mujoco.h>

#include "fmi2_plumbing.h"
#include "kernel_mujoco.h"
#include "kernel_util.h"

#define MAX_DIM 4096
#define MAX_PATH_BYTES 4096
#define MAX_SIZE 1000000

/* The ports' names, causalities and types by id (kernel_mujoco_ports.h, generated). */
static const char *const PORT_NAME[UIOFMU_MUJOCO_PORTS] = UIOFMU_MUJOCO_PORT_NAMES;
static const int PORT_CAUSALITY[UIOFMU_MUJOCO_PORTS] = UIOFMU_MUJOCO_PORT_CAUSALITIES;
static const int PORT_TYPE[UIOFMU_MUJOCO_PORTS] = UIOFMU_MUJOCO_PORT_TYPES;

static const char *const FIELD_NAME[UIOFMU_MJ_FIELDS] = {"body_mass", "jnt_stiffness", "dof_damping",
                                                         "tendon_stiffness", "tendon_damping", "actuator_gear"};

typedef struct {
    FmuInstance *fmu;
    const UiofmuMujoco *d;
    mjModel *model;
    mjData *data;
    double *x0, *params, *defaults, *u, *dv, *x, *y;
    int dirty;
    double *block; /* every double above, one allocation */
} Mujoco;

/* ---------------------------------------------------------------------------------------- */
/* The design, checked once at fmi2Instantiate                                               */

static int mujoco_check_design(char *msg, size_t len) {
    const UiofmuMujoco *d = &UIOFMU_MUJOCO;
    const int dims[12] = {d->n, d->m, d->p, d->q, d->nparams, d->nq, d->nv, d->nu, d->na, d->nbody, d->njnt,
                          d->ntendon};
    const int low[12] = {2, 0, 1, 1, 0, 1, 1, 1, 0, 1, 1, 0};
    const char *const names[12] = {"n", "m", "p", "q", "nparams", "nq", "nv", "nu", "na", "nbody", "njnt", "ntendon"};
    if (!uiofmu_check_dims(msg, len, "MuJoCo plant dims.", 12, dims, names, low, MAX_DIM)) return 0;
    if (d->n % 2)
        return uiofmu_design_error(msg, len, "MuJoCo plant dims.n = %d: expected twice the number of joints", d->n);
    if (!(isfinite(d->dt) && d->dt > 0) || !(d->max_substeps >= 1))
        return uiofmu_design_error(msg, len, "MuJoCo plant dt = %g, max_substeps = %d: expected a substep > 0 and "
                                   "at least one substep", d->dt, d->max_substeps);
    if (d->integrator < mjINT_EULER || d->integrator > mjINT_IMPLICITFAST)
        return uiofmu_design_error(msg, len, "MuJoCo plant integrator = %d is none of MuJoCo's 0 to %d",
                                   d->integrator, (int)mjINT_IMPLICITFAST);
    const int k = d->n / 2;
    const struct { const char *name; const int *data; size_t length; int want, below; } I[6] = {
        {"qadr", d->qadr, d->qadr_length, k, d->nq}, {"vadr", d->vadr, d->vadr_length, k, d->nv},
        {"uid", d->uid, d->uid_length, d->m, d->nu}, {"did", d->did, d->did_length, d->q, d->nu},
        {"param_field", d->param_field, d->param_field_length, d->nparams, UIOFMU_MJ_FIELDS},
        {"param_index", d->param_index, d->param_index_length, d->nparams, MAX_SIZE},
    };
    for (int i = 0; i < 6; i++) {
        if (!I[i].data || I[i].length != (size_t)(I[i].want ? I[i].want : 1))
            return uiofmu_design_error(msg, len, "MuJoCo plant %s: %zu numbers, expected %d", I[i].name,
                                       I[i].data ? I[i].length : 0, I[i].want);
        for (int e = 0; e < I[i].want; e++)
            if (I[i].data[e] < 0 || I[i].data[e] >= I[i].below)
                return uiofmu_design_error(msg, len, "MuJoCo plant %s[%d] = %d is out of range [0, %d)", I[i].name, e,
                                           I[i].data[e], I[i].below);
    }
    const struct { const char *name; const double *data; size_t length, want; } M[2] = {
        {"C", d->C, d->C_length, (size_t)d->p * (size_t)d->n}, {"x0", d->x0, d->x0_length, (size_t)d->n}};
    for (int i = 0; i < 2; i++) {
        if (!M[i].data || M[i].length != M[i].want)
            return uiofmu_design_error(msg, len, "MuJoCo plant %s: %zu numbers, expected %zu", M[i].name,
                                       M[i].data ? M[i].length : 0, M[i].want);
        for (size_t e = 0; e < M[i].want; e++)
            if (!isfinite(M[i].data[e]))
                return uiofmu_design_error(msg, len, "MuJoCo plant %s: entry %zu is not finite", M[i].name, e + 1);
    }
    return 1;
}

static int mujoco_port(int id, UiofmuPort *out) {
    const UiofmuMujoco *d = &UIOFMU_MUJOCO;
    int size;
    switch (id) {
    case UIOFMU_MUJOCO_X0: case UIOFMU_MUJOCO_X: size = d->n; break;
    case UIOFMU_MUJOCO_PARAMS: size = d->nparams; break;
    case UIOFMU_MUJOCO_U: size = d->m; break;
    case UIOFMU_MUJOCO_D: size = d->q; break;
    case UIOFMU_MUJOCO_Y: size = d->p; break;
    default: return 0;
    }
    out->name = PORT_NAME[id];
    out->size = size;
    out->causality = PORT_CAUSALITY[id];
    out->type = PORT_TYPE[id];
    return 1;
}

/* ---------------------------------------------------------------------------------------- */
/* The model: its file, its checks, its parameters                                           */

/* The model array of a physical parameter and its length in the loaded model. */
static mjtNum *field_array(const mjModel *m, int field, size_t *length) {
    switch (field) {
    case UIOFMU_MJ_BODY_MASS: *length = (size_t)m->nbody; return m->body_mass;
    case UIOFMU_MJ_JNT_STIFFNESS: *length = (size_t)m->njnt; return m->jnt_stiffness;
    case UIOFMU_MJ_DOF_DAMPING: *length = (size_t)m->nv; return m->dof_damping;
    case UIOFMU_MJ_TENDON_STIFFNESS: *length = (size_t)m->ntendon; return m->tendon_stiffness;
    case UIOFMU_MJ_TENDON_DAMPING: *length = (size_t)m->ntendon; return m->tendon_damping;
    default: *length = (size_t)m->nout * 6; return m->actuator_gear;
    }
}

/* Whether the loaded model is the one the indices were resolved in (its sizes, every parameter's
   element within its array); else 0 after a log line. */
static int model_fits(FmuInstance *fmu, const mjModel *m, const UiofmuMujoco *d, const char *path) {
    const long have[7] = {(long)m->nq, (long)m->nv, (long)m->nu, (long)m->na, (long)m->nbody, (long)m->njnt,
                          (long)m->ntendon};
    const int want[7] = {d->nq, d->nv, d->nu, d->na, d->nbody, d->njnt, d->ntendon};
    static const char *const NAME[7] = {"nq", "nv", "nu", "na", "nbody", "njnt", "ntendon"};
    for (int i = 0; i < 7; i++)
        if (have[i] != want[i]) {
            uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: the model of %.300s has %s = %ld, the FMU was built for %d "
                       "(the MJCF was changed after the build)", path, NAME[i], have[i], want[i]);
            return 0;
        }
    for (int i = 0; i < d->nparams; i++) {
        size_t length;
        field_array(m, d->param_field[i], &length);
        if ((size_t)d->param_index[i] >= length) {
            uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: physical parameter %d sets %s element %d, which the model of "
                       "%.300s does not have", i + 1, FIELD_NAME[d->param_field[i]], d->param_index[i], path);
            return 0;
        }
    }
    return 1;
}

static void write_parameters(Mujoco *s) {
    for (int i = 0; i < s->d->nparams; i++) {
        size_t length;
        field_array(s->model, s->d->param_field[i], &length)[s->d->param_index[i]] = s->params[i];
    }
}

/* The reference runtime's reset: mj_resetData, the joints at x0, mj_forward. */
static void start_at_x0(Mujoco *s) {
    const UiofmuMujoco *d = s->d;
    int k = d->n / 2;
    mj_resetData(s->model, s->data);
    for (int i = 0; i < k; i++) {
        s->data->qpos[d->qadr[i]] = s->x0[i];
        s->data->qvel[d->vadr[i]] = s->x0[k + i];
    }
    mj_forward(s->model, s->data);
    s->dirty = 1;
}

/* ---------------------------------------------------------------------------------------- */
/* Instances                                                                                 */

static void mujoco_free(void *self) {
    Mujoco *s = (Mujoco *)self;
    if (!s) return;
    if (s->data) mj_deleteData(s->data);
    if (s->model) mj_deleteModel(s->model);
    free(s->block);
    free(s);
}

static void mujoco_reset(void *self) {
    Mujoco *s = (Mujoco *)self;
    const UiofmuMujoco *d = s->d;
    memcpy(s->x0, d->x0, (size_t)d->n * sizeof(double));
    memcpy(s->params, s->defaults, (size_t)d->nparams * sizeof(double));
    memset(s->u, 0, (size_t)d->m * sizeof(double));
    memset(s->dv, 0, (size_t)d->q * sizeof(double));
    write_parameters(s);
    start_at_x0(s);
}

static void *mujoco_instantiate(FmuInstance *fmu) {
    const UiofmuMujoco *d = &UIOFMU_MUJOCO;
    char path[MAX_PATH_BYTES], error[1000] = "";
    if (mj_version() != d->version) {
        uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: the libmujoco in this process is version %d (%s), the FMU was "
                   "built with %d", mj_version(), mj_versionString(), d->version);
        return NULL;
    }
    if (!uiofmu_resource_path(fmu, UIOFMU_MJCF_FILE, path, sizeof path)) return NULL;
    Mujoco *s = (Mujoco *)uiofmu_alloc(fmu, 1, sizeof(Mujoco));
    if (!s) return NULL;
    s->fmu = fmu;
    s->d = d;
    s->model = mj_loadXML(path, NULL, error, sizeof error);
    if (!s->model) {
        uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: MuJoCo cannot load %.300s: %.400s", path, error);
        mujoco_free(s);
        return NULL;
    }
    if (!model_fits(fmu, s->model, d, path)) {
        mujoco_free(s);
        return NULL;
    }
    s->model->opt.integrator = d->integrator;
    s->model->opt.timestep = d->dt;
    s->data = mj_makeData(s->model);
    size_t n = (size_t)d->n, P = (size_t)d->nparams;
    s->block = s->data ? (double *)uiofmu_alloc(fmu, 3 * n + 2 * P + (size_t)(d->m + d->q + d->p), sizeof(double))
                       : NULL;
    if (!s->block) {
        if (!s->data) uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: MuJoCo could not make the model's data");
        mujoco_free(s);
        return NULL;
    }
    double *b = s->block;
    s->x0 = b; b += n;
    s->x = b; b += n;
    s->params = b; b += P;
    s->defaults = b; b += P;
    s->u = b; b += d->m;
    s->dv = b; b += d->q;
    s->y = b;
    for (int i = 0; i < d->nparams; i++) {
        size_t length;
        s->defaults[i] = field_array(s->model, d->param_field[i], &length)[d->param_index[i]];
    }
    mujoco_reset(s);
    return s;
}

static UiofmuResult mujoco_exit_initialization(void *self) {
    Mujoco *s = (Mujoco *)self;
    char b1[32];
    if (!uiofmu_parameter_finite(s->fmu, PORT_NAME[UIOFMU_MUJOCO_X0], s->x0, s->d->n)) return UIOFMU_REFUSED;
    for (int i = 0; i < s->d->nparams; i++)
        if (!isfinite(s->params[i])) {
            uiofmu_log(s->fmu, fmi2Error, "physical parameter %d (%s) = %s is not finite", i + 1,
                       FIELD_NAME[s->d->param_field[i]], uiofmu_num(s->params[i], b1));
            return UIOFMU_REFUSED;
        }
    write_parameters(s);
    start_at_x0(s);
    return UIOFMU_DONE;
}

static UiofmuResult mujoco_calculate(void *self, const char *fn) {
    Mujoco *s = (Mujoco *)self;
    const UiofmuMujoco *d = s->d;
    int k = d->n / 2;
    (void)fn;
    if (!s->dirty) return UIOFMU_DONE;
    for (int i = 0; i < k; i++) {
        s->x[i] = s->data->qpos[d->qadr[i]];
        s->x[k + i] = s->data->qvel[d->vadr[i]];
    }
    for (int i = 0; i < d->p; i++) {
        double acc = 0.0;
        for (int j = 0; j < d->n; j++) acc += d->C[(size_t)i * d->n + j] * s->x[j];
        s->y[i] = acc;
    }
    s->dirty = 0;
    return UIOFMU_DONE;
}

/* The storage of element `index` of port `port` (the plumbing checked both against the table). */
static double *mujoco_real_storage(void *self, int port, int index) {
    Mujoco *s = (Mujoco *)self;
    double *const first[UIOFMU_MUJOCO_PORTS] = {[UIOFMU_MUJOCO_X0] = s->x0, [UIOFMU_MUJOCO_PARAMS] = s->params,
                                                [UIOFMU_MUJOCO_U] = s->u, [UIOFMU_MUJOCO_D] = s->dv,
                                                [UIOFMU_MUJOCO_Y] = s->y, [UIOFMU_MUJOCO_X] = s->x};
    return uiofmu_element(first, port, index);
}

/* The plumbing stored new values: nothing to note (the outputs follow the state alone, which
   only a step and the start of the run change). */
static void mujoco_changed(void *self) { (void)self; }

static UiofmuResult mujoco_step(void *self, double t, double h) {
    Mujoco *s = (Mujoco *)self;
    const UiofmuMujoco *d = s->d;
    mjModel *m = s->model;
    mjData *data = s->data;
    char bt[32];
    uiofmu_num(t, bt);
    if (!uiofmu_inputs_finite(s->fmu, t, -1, s->u, d->m, PORT_NAME[UIOFMU_MUJOCO_U]) ||
        !uiofmu_inputs_finite(s->fmu, t, -1, s->dv, d->q, PORT_NAME[UIOFMU_MUJOCO_D]))
        return UIOFMU_REFUSED;
    double count = h / d->dt - 1e-9;
    if (!(count <= d->max_substeps)) {
        uiofmu_log(s->fmu, fmi2Discard, "t = %s: communication step h = %.6g s needs %.3g MuJoCo steps (at most "
                   "%.3g s each), more than the %d a step may take: take steps of at most %.6g s", bt, h, count + 1e-9, d->dt, d->max_substeps, d->max_substeps * d->dt);
        return UIOFMU_DISCARDED;
    }
    for (int i = 0; i < d->m; i++) data->ctrl[d->uid[i]] = s->u[i];
    for (int i = 0; i < d->q; i++) data->ctrl[d->did[i]] = s->dv[i];
    double t_end = data->time + h;
    long full = (long)floor(h / d->dt + 1e-9);
    double rest = h - (double)full * d->dt;
    int warned[mjNWARNING];
    for (int i = 0; i < mjNWARNING; i++) warned[i] = data->warning[i].number;
    for (long i = 0; i < full; i++) mj_step(m, data);
    if (rest > 1e-9 * d->dt) {
        m->opt.timestep = rest;
        mj_step(m, data);
        m->opt.timestep = d->dt;
    }
    data->time = t_end;
    s->dirty = 1;
    for (int i = 0; i < mjNWARNING; i++)
        if (data->warning[i].number != warned[i])
            uiofmu_log(s->fmu, fmi2Warning, "t = %s: MuJoCo warned %d time(s) in the step of h = %.6g s: %s", bt,
                       data->warning[i].number - warned[i], h,
                       mju_warningText(i, (size_t)data->warning[i].lastinfo));
    return UIOFMU_DONE;
}

/* ---------------------------------------------------------------------------------------- */
/* FMU state (layout in the header comment)                                                  */

typedef unsigned char Byte;

static size_t mujoco_state_count(void) {
    const UiofmuMujoco *d = &UIOFMU_MUJOCO;
    return 2 + (size_t)(d->n + d->nparams + d->m + d->q + d->nq + d->nv + d->na + d->nu);
}

static void mujoco_state_shape(uint32_t shape[UIOFMU_SHAPE], const char *names[UIOFMU_SHAPE]) {
    const UiofmuMujoco *d = &UIOFMU_MUJOCO;
    static const char *const NAMES[UIOFMU_SHAPE] = {"nq", "nv", "na", "nu"};
    const int dims[UIOFMU_SHAPE] = {d->nq, d->nv, d->na, d->nu};
    uiofmu_shape(shape, names, dims, NAMES);
}

static void mujoco_save_state(void *self, int phase, Byte *o) {
    Mujoco *s = (Mujoco *)self;
    const UiofmuMujoco *d = s->d;
    double head[2] = {(double)phase, s->data->time};
    o = uiofmu_put(o, head, 2);
    o = uiofmu_put(o, s->x0, (size_t)d->n);
    o = uiofmu_put(o, s->params, (size_t)d->nparams);
    o = uiofmu_put(o, s->u, (size_t)d->m);
    o = uiofmu_put(o, s->dv, (size_t)d->q);
    o = uiofmu_put(o, s->data->qpos, (size_t)d->nq);
    o = uiofmu_put(o, s->data->qvel, (size_t)d->nv);
    o = uiofmu_put(o, s->data->act, (size_t)d->na);
    uiofmu_put(o, s->data->ctrl, (size_t)d->nu);
}

static int mujoco_check_state(void *self, const char *ctx, const Byte *v, int *phase) {
    Mujoco *s = (Mujoco *)self;
    const UiofmuMujoco *d = s->d;
    char b1[32];
    double ph = uiofmu_getd(v, 0), time = uiofmu_getd(v, 1);
    if (!uiofmu_phase_ok(s->fmu, ctx, ph)) return 0;
    if (!(isfinite(time) && time >= 0))
        return uiofmu_state_refused(s->fmu, ctx, "time = %s: expected a finite time >= 0", uiofmu_num(time, b1));
    /* the finite parts, in order; u[m] and d[q] between params and qpos are taken as they are */
    const struct { const char *name; size_t at; int count; } F[6] = {
        {"x0", 2, d->n}, {"params", 2 + (size_t)d->n, d->nparams},
        {"qpos", 2 + (size_t)(d->n + d->nparams + d->m + d->q), d->nq},
        {"qvel", 2 + (size_t)(d->n + d->nparams + d->m + d->q + d->nq), d->nv},
        {"act", 2 + (size_t)(d->n + d->nparams + d->m + d->q + d->nq + d->nv), d->na},
        {"ctrl", 2 + (size_t)(d->n + d->nparams + d->m + d->q + d->nq + d->nv + d->na), d->nu},
    };
    for (int f = 0; f < 6; f++)
        for (int i = 0; i < F[f].count; i++) {
            double x = uiofmu_getd(v, F[f].at + (size_t)i);
            if (!isfinite(x))
                return uiofmu_state_refused(s->fmu, ctx, "%s[%d] = %s is not finite", F[f].name, i + 1,
                                            uiofmu_num(x, b1));
        }
    *phase = (int)ph;
    return 1;
}

static void mujoco_load_state(void *self, const Byte *v) {
    Mujoco *s = (Mujoco *)self;
    const UiofmuMujoco *d = s->d;
    mjData *data = s->data;
    const Byte *o = v + 2 * sizeof(double);
    o = uiofmu_take(o, s->x0, (size_t)d->n);
    o = uiofmu_take(o, s->params, (size_t)d->nparams);
    o = uiofmu_take(o, s->u, (size_t)d->m);
    o = uiofmu_take(o, s->dv, (size_t)d->q);
    write_parameters(s);
    o = uiofmu_take(o, data->qpos, (size_t)d->nq);
    o = uiofmu_take(o, data->qvel, (size_t)d->nv);
    o = uiofmu_take(o, data->act, (size_t)d->na);
    uiofmu_take(o, data->ctrl, (size_t)d->nu);
    data->time = uiofmu_getd(v, 1);
    mj_forward(s->model, data);
    s->dirty = 1;
}

const UiofmuKernel UIOFMU_KERNEL_MUJOCO = {
    .name = "MuJoCo plant",
    .check_design = mujoco_check_design,
    .ports = UIOFMU_MUJOCO_PORTS,
    .port = mujoco_port,
    .instantiate = mujoco_instantiate,
    .free_instance = mujoco_free,
    .reset = mujoco_reset,
    .exit_initialization = mujoco_exit_initialization,
    .calculate = mujoco_calculate,
    .real_storage = mujoco_real_storage,
    .changed = mujoco_changed,
    .get_integer = NULL,
    .set_integer = NULL,
    .step = mujoco_step,
    .state_count = mujoco_state_count,
    .state_shape = mujoco_state_shape,
    .save_state = mujoco_save_state,
    .check_state = mujoco_check_state,
    .load_state = mujoco_load_state,
};

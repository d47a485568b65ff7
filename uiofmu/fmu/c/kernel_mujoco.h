/* uiofmu: the MuJoCo plant kernel's ports and design data (kernel_mujoco.c reads them).
 *
 * A MuJoCo plant (uiofmu/mujoco_plant.py, the [mujoco] table of its mujoco.toml) becomes one
 * constant UiofmuMujoco (design_data.c, generated; numbers only). uiofmu resolves every name of
 * the spec (joints, actuators, the objects of the physical parameters) against the MJCF with
 * MuJoCo at build time, so what is compiled in are MuJoCo's own indices, the sizes of the model
 * they index, and the settings the reference runtime (uiofmu/runtime/mujoco_runtime.py) gives it.
 * fmi2Instantiate loads the MJCF from resources/ and checks the model it gets against those sizes
 * before it uses any index. Arrays are row-major and travel with their lengths (UIOFMU_LENGTH):
 *   qadr k, vadr k (the joints' qpos and qvel addresses, n = 2k), uid m, did q (actuator ids),
 *   param_field P, param_index P (which model array and which element each physical parameter
 *   sets), C p x n, x0 n.
 * An empty array (m = 0, P = 0) is written as {0}: length 1.
 */
#ifndef UIOFMU_KERNEL_MUJOCO_H
#define UIOFMU_KERNEL_MUJOCO_H

#include <stddef.h>

#include "fmi2_plumbing.h"

/* The ports the kernel implements (uiofmu.runtime.ports.plant_ports with the physical parameters):
   x0[n] parameter, the physical parameters (one Real parameter port each, all of them elements of
   the kernel's port params), u[m] and d[q] inputs (held over the step), y[p] = C x and x[n]
   outputs. Ids, names, causalities and types are generated from uiofmu/runtime/ports.py
   (KERNEL_PORTS["mujoco"]). */
#include "kernel_mujoco_ports.h"

/* The model arrays a physical parameter may set (uiofmu.runtime.mujoco_runtime.PARAMETER_FIELDS). */
enum {
    UIOFMU_MJ_BODY_MASS, UIOFMU_MJ_JNT_STIFFNESS, UIOFMU_MJ_DOF_DAMPING, UIOFMU_MJ_TENDON_STIFFNESS,
    UIOFMU_MJ_TENDON_DAMPING, UIOFMU_MJ_ACTUATOR_GEAR, UIOFMU_MJ_FIELDS
};

typedef struct {
    int n, m, p, q, nparams;
    /* the sizes of the model the indices were resolved in (mjModel's), and the MuJoCo it was
       built with (mj_version()) */
    int nq, nv, nu, na, nbody, njnt, ntendon;
    int version;
    int integrator;       /* mjtIntegrator */
    double dt;            /* the fixed substep (mjOption.timestep), s */
    int max_substeps;     /* the most substeps of one communication step */
    const int *qadr, *vadr, *uid, *did, *param_field, *param_index;
    const double *C, *x0;
    size_t qadr_length, vadr_length, uid_length, did_length, param_field_length, param_index_length, C_length,
        x0_length;
} UiofmuMujoco;

UIOFMU_INTERNAL extern const UiofmuMujoco UIOFMU_MUJOCO;

/* The name of the MJCF file in the FMU's resources/. */
#define UIOFMU_MJCF_FILE "model.xml"

/* The kernel, for UIOFMU_FMU.kernel. */
UIOFMU_INTERNAL extern const UiofmuKernel UIOFMU_KERNEL_MUJOCO;

#endif

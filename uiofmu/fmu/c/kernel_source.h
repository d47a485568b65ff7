/* uiofmu: the signal-source kernel's ports and design data (kernel_source.c reads them).
 *
 * A signal source plays a table of inputs as outputs: u[m], d[q], theta[s] (Real) and mode[1]
 * (Integer), each row held from its time until the next row's. design_data.c (generated) holds
 * only the sizes; the table itself is data in the FMU's resources/ (TABLE_FILE, below), read at
 * fmi2Instantiate and checked against these sizes before any of it is used.
 *
 * The table file, little-endian:
 *   8 bytes   "UIOSIG01"
 *   uint64    rows (1 .. 2^26)
 *   uint64    columns (m + q + s + modes, as compiled in)
 *   rows x (1 + columns) doubles, row-major: the row's time, then its values in the order
 *             u[1..m], d[1..q], theta[1..s], mode
 * Times finite and not decreasing, values finite, a mode an integer from -2^31 to 2^31 - 1.
 */
#ifndef UIOFMU_KERNEL_SOURCE_H
#define UIOFMU_KERNEL_SOURCE_H

#include <stddef.h>

#include "fmi2_plumbing.h"

/* The ports the kernel implements (ids, names, causalities, types), generated at build time from
   uiofmu/runtime/ports.py (KERNEL_PORTS["source"]). */
#include "kernel_source_ports.h"

/* The table's file in the FMU's resources/. */
#define UIOFMU_SOURCE_TABLE_FILE "signals.bin"

typedef struct {
    int m, q, s; /* elements of u, d, theta */
    int modes;   /* 1 when the source plays mode, else 0 */
} UiofmuSource;

UIOFMU_INTERNAL extern const UiofmuSource UIOFMU_SOURCE;

/* The kernel, for UIOFMU_FMU.kernel. */
UIOFMU_INTERNAL extern const UiofmuKernel UIOFMU_KERNEL_SOURCE;

#endif

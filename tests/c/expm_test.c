/* expm_test: uiofmu_expm of the C plant kernel (kernel_plant.c, linked with a plant FMU's sources),
 * built by tests/test_matrix_exponential.py:
 *
 *   expm_test < MATRICES    each matrix on stdin as "k" and its k x k entries row by row (any text
 *                           strtod reads back exactly, such as Python's repr); for each one line on
 *                           stdout: its exponential's entries row by row in hexadecimal (%a), or
 *                           "refused" when uiofmu_expm returns 0
 *
 * Exits 1 on input it cannot read, 0 otherwise.
 */
#include <stdio.h>
#include <stdlib.h>

#include "fmi2_plumbing.h"
#include "kernel_plant.h"

int main(void) {
    int k;
    while (scanf("%d", &k) == 1) {
        if (k < 1 || k > 64) return 1;
        size_t kk = (size_t)k * (size_t)k;
        double *M = malloc(kk * sizeof(double)), *out = malloc(kk * sizeof(double));
        double *work = malloc(7 * kk * sizeof(double));
        int *piv = malloc((size_t)k * sizeof(int));
        if (!M || !out || !work || !piv) return 1;
        for (size_t e = 0; e < kk; e++) {
            char word[64];
            if (scanf("%63s", word) != 1) return 1;
            M[e] = strtod(word, NULL);
        }
        if (uiofmu_expm(M, k, out, work, piv)) {
            for (size_t e = 0; e < kk; e++) printf(e ? " %a" : "%a", out[e]);
            printf("\n");
        } else {
            printf("refused\n");
        }
        free(M); free(out); free(work); free(piv);
    }
    return 0;
}

/* Washout matrices of one macro step: the C port of immersim.models.platform.cueing.washout_matrices.
 *
 * continuous_system (block-diagonal companion forms of the translational, rotational and
 * tilt-coordination filters), the exact zero-order-hold discretisation exp([[A, B], [0, 0]] h) by
 * scaling and squaring of a 20-term Taylor series (cueing.expm_small) and the packing
 * (Phi 19x19, Gamma 19x7, C 8x19, column-major, then sin(tilt_max), tilt_rate h, g). Every
 * floating-point operation is the Python one in the same order, so both builds hold the same bits
 * (compile without contraction into fused multiply-adds: -ffp-contract=off).
 */
#include <math.h>
#include <string.h>

#include "platform_native.h"

#define NA (PLATFORM_NW + 7)  /* augmented matrix [[A, B], [0, 0]] */

/* out = a b, each entry summed in order k = 0, 1, ... (cueing._matmul) */
static void matmul(const double a[NA][NA], const double b[NA][NA], double out[NA][NA]) {
  int i, j, k;
  double acc;
  for (i = 0; i < NA; ++i)
    for (j = 0; j < NA; ++j) {
      acc = a[i][0] * b[0][j];
      for (k = 1; k < NA; ++k) acc = acc + a[i][k] * b[k][j];
      out[i][j] = acc;
    }
}

/* companion block of num(s)/den(s) (den monic, degree n, high -> low) at row/column offset o */
static void companion(double A[NA][NA], double C[8][PLATFORM_NW], int row, int o, int n, const double* den,
                      const double* num, int nnum) {
  int j;
  for (j = 0; j + 1 < n; ++j) A[o + j][o + j + 1] = 1.0;
  for (j = 0; j < n; ++j) A[o + n - 1][o + j] = -den[n - j];
  for (j = 0; j < nnum; ++j) C[row][o + j] = num[nnum - 1 - j];
}

void platform_washout_matrices(const double* wp, double h, double* wm) {
  /* wp: washout parameters in WashoutParams order (k_t, omega_t, zeta_t, omega_b, k_r, omega_r,
     zeta_r, omega_tc, tilt_max, tilt_rate, jolt_heave, g) */
  const double k_t = wp[0], omega_t = wp[1], zeta_t = wp[2], omega_b = wp[3], k_r = wp[4], omega_r = wp[5];
  const double zeta_r = wp[6], omega_tc = wp[7], tilt_max = wp[8], tilt_rate = wp[9], jolt_heave = wp[10];
  const double g = wp[11];
  static const int tr_in[3] = {0, 1, 2}, rot_in[3] = {3, 4, 5};
  double M[NA][NA], C[8][PLATFORM_NW], X[NA][NA], E[NA][NA], term[NA][NA], tmp[NA][NA];
  double a1 = 2.0 * zeta_t * omega_t, a0 = pow(omega_t, 2.0);
  double tr_den[4], rot_den[3], lp_den[3], tr_num[2], rot_num[2], lp_num[1];
  double colsum[NA], norm, scale;
  int i, j, k, o = 0, s = 0;

  tr_den[0] = 1.0; tr_den[1] = a1 + omega_b; tr_den[2] = a0 + a1 * omega_b; tr_den[3] = a0 * omega_b;
  rot_den[0] = 1.0; rot_den[1] = 2.0 * zeta_r * omega_r; rot_den[2] = pow(omega_r, 2.0);
  lp_den[0] = 1.0; lp_den[1] = 2.0 * omega_tc; lp_den[2] = pow(omega_tc, 2.0);
  tr_num[0] = k_t; tr_num[1] = 0.0; rot_num[0] = k_r; rot_num[1] = 0.0; lp_num[0] = pow(omega_tc, 2.0);
  memset(M, 0, sizeof M);
  memset(C, 0, sizeof C);
  for (i = 0; i < 3; ++i, o += 3) {  /* translation x, y, z: inputs f_x, f_y, f_z */
    companion(M, C, i, o, 3, tr_den, tr_num, 2);
    M[o + 2][PLATFORM_NW + tr_in[i]] = 1.0;
  }
  for (i = 0; i < 3; ++i, o += 2) {  /* rotation gamma, beta, alpha: inputs w_x, w_y, w_z */
    companion(M, C, 3 + i, o, 2, rot_den, rot_num, 2);
    M[o + 1][PLATFORM_NW + rot_in[i]] = 1.0;
  }
  for (i = 0; i < 2; ++i, o += 2) {  /* tilt low-pass of f_x, f_y */
    companion(M, C, 6 + i, o, 2, lp_den, lp_num, 1);
    M[o + 1][PLATFORM_NW + i] = 1.0;
  }
  M[2][PLATFORM_NW + 6] = 1.0;          /* jolt: surge block */
  M[8][PLATFORM_NW + 6] = jolt_heave * 1.0;  /* and jolt_heave x heave block */
  for (i = 0; i < NA; ++i)
    for (j = 0; j < NA; ++j) M[i][j] = M[i][j] * h;

  /* expm_small: 1-norm by rows in order, scaling by exact halvings, Taylor, squaring */
  for (j = 0; j < NA; ++j) colsum[j] = fabs(M[0][j]);
  for (i = 1; i < NA; ++i)
    for (j = 0; j < NA; ++j) colsum[j] = colsum[j] + fabs(M[i][j]);
  norm = colsum[0];
  for (j = 1; j < NA; ++j) if (colsum[j] > norm) norm = colsum[j];
  while (norm > 0.5) { norm = norm / 2.0; ++s; }
  scale = pow(2.0, (double) s);
  for (i = 0; i < NA; ++i)
    for (j = 0; j < NA; ++j) {
      X[i][j] = M[i][j] / scale;
      E[i][j] = term[i][j] = (i == j) ? 1.0 : 0.0;
    }
  for (k = 1; k <= 20; ++k) {
    matmul((const double (*)[NA]) term, (const double (*)[NA]) X, tmp);
    for (i = 0; i < NA; ++i)
      for (j = 0; j < NA; ++j) {
        term[i][j] = tmp[i][j] / (double) k;
        E[i][j] = E[i][j] + term[i][j];
      }
  }
  for (k = 0; k < s; ++k) {
    matmul((const double (*)[NA]) E, (const double (*)[NA]) E, tmp);
    memcpy(E, tmp, sizeof E);
  }
  /* pack: Phi, Gamma, C column-major, then sin(tilt_max), tilt_rate h, g */
  o = 0;
  for (j = 0; j < PLATFORM_NW; ++j)
    for (i = 0; i < PLATFORM_NW; ++i) wm[o++] = E[i][j];
  for (j = 0; j < 7; ++j)
    for (i = 0; i < PLATFORM_NW; ++i) wm[o++] = E[i][PLATFORM_NW + j];
  for (j = 0; j < PLATFORM_NW; ++j)
    for (i = 0; i < 8; ++i) wm[o++] = C[i][j];
  wm[o++] = sin(tilt_max);
  wm[o++] = tilt_rate * h;
  wm[o++] = g;
}

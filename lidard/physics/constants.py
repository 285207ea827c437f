"""Physical constants (CODATA 2018 exact SI values where defined)."""

C_M_PER_S = 299_792_458.0
E_CHARGE_C = 1.602_176_634e-19
K_BOLTZMANN_J_PER_K = 1.380_649e-23
H_PLANCK_J_S = 6.626_070_15e-34

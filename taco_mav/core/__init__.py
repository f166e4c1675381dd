"""Pure estimator maths (TACO, paper Sec. III). Imports numpy, scipy, numba and, for the offline smoother only,
gtsam: no I/O. (filterpy is the tests' reference for the UKF, not imported here.)"""

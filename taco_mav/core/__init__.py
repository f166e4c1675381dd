"""Pure estimator maths (TACO, paper Sec. III). Imports numpy, scipy, filterpy and gtsam only: no I/O."""

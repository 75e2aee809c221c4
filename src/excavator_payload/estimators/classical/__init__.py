"""Model-based payload estimators: the EKF and UKF with the payload as a state (``ekf``,
``ukf``), inverse-dynamics least squares (``inverse-dynamics``), the calibrated inverse dynamics
that first identifies the arm's base parameters (``calibrated``) and the industry's quasi-static
baseline (``quasi-static``), with their kernels for the machine sensor set."""

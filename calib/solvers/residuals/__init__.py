"""Residual blocks: one module per kind of row (measured poses and positions: :mod:`.pose`;
points, planes and spheres touched: :mod:`.touch`), each giving its rows' residuals, their
Jacobian columns (the robot's free parameters and its own unknowns) and their groups (the
whitening). :class:`calib.solvers.blocks.BlockProblem` assembles them into one problem."""

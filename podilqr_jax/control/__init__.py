"""Control: a finished solve as a controller, the Kalman estimator, receding-horizon replanning."""

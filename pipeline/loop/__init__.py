"""The closed loop: the Gymnasium-style environment, its checker, one rollout with deadlines."""

"""Pure metrics over recorded rollouts, reports and plots."""

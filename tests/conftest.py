"""Import the simulator package first: it selects the GL back-end and XLA's CPU flags,
which must happen before MuJoCo renders or JAX initialises."""
import envs  # noqa: F401

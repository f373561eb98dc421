"""Backend plugins (torch-cpu; jax-mjx later)."""

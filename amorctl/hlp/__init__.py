"""The high-level policy (paper Section 6): an HLP picks the weights ``w_t`` of a frozen AMOR policy
every control step, trained with PPO on a discriminator reward. See ``docs/hlp.md``."""

"""Built-in characters: ``humanoid36`` (DeepMimic humanoid) and ``biped20`` (Robotis OP3)."""

"""Motion data: importers, retargeting, frames, the motion VAE and the MCAP dataset."""

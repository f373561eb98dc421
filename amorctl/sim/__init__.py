"""MuJoCo model loading and simulation helpers shared by characters, motion data and backends."""

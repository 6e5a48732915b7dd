"""End-to-end jobs: the demo, the toy experiment and its comparison over seeds, and the sweeps."""

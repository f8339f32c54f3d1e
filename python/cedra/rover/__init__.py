"""The CEDRA rover: its mechanism (transform chains, bodies, joint forces), its numbers, the paper's kinematics."""

"""Generic mechanics, no CEDRA numbers: transforms, Kane's method, terrain kinds, wheel-ground contact, heightmaps."""

"""The simulator: pipe networks, wall textures, LED lighting, camera sensor and renderer."""

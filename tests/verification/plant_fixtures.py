"""Plants shared by several test files."""

#: DC motor: current i, speed w, angle th (R=1, L=0.01, J=0.01, b=0.001, Kt=Ke=0.5).
MOTOR = {
    "ss": {
        "A": [[-100.0, -50.0, 0.0], [50.0, -0.1, 0.0], [0.0, 1.0, 0.0]],
        "B": [[100.0], [0.0], [0.0]],
        "C": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        "states": ["i", "w", "th"],
        "outputs": ["i", "w", "th"],
    }
}

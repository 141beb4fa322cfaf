"""sumo_scenarios: SUMO towns, seeded dense traffic, fcd logs and lane queries.

Knows nothing of ``asg``; ``asg`` builds scenes from what this package records.
"""

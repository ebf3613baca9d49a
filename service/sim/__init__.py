"""Simulation on the station's side: the virtual actuator that publishes a model's samples and
the bundled scenarios. May import models, compat, wire and the loose utilities.
"""

"""The wire: the messages on Zenoh (samples in, faults, outputs, key expressions), their binary
format and its compiled decoder. May import models, compat, log, monitor and the loose utilities.
"""

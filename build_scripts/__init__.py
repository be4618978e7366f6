"""Building the FMI 2.0 co-simulation FMUs (``tapmuscle build``)."""

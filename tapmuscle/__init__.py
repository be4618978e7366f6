"""tapmuscle: command line, recordings and figures around the plant (fmu_plant) and the identification
and control numerics (fmu_controller). Nothing in the numerics packages reads or writes files; this
package does."""

__version__ = "0.1.0"

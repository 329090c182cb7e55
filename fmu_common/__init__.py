"""What every FMU of flexpend carries and no model owns.

* :mod:`fmu_common.variables`: the variable table an FMU is described by (one per model);
* :mod:`fmu_common.checks`: the validation of parameter values, for every parameter record;
* :mod:`fmu_common.slave`: the base of the pythonfmu slaves (registration from the table, the
  guard that never lets Python raise into pythonfmu, FMU states);
* :mod:`fmu_common.kernels`: where the compiled C kernels live, how they are built and loaded;
* ``native/``: the FMI 2.0 and FMI 3.0 layers of the native FMUs, written once for every model;
* ``loader/``: the loader that stands in front of pythonfmu's library in the pythonfmu FMUs.

Standard library only (numpy and pythonfmu for the slave base): a model package imports from
here, never from another model or from the host side.
"""

"""An FMU as an ECU function (FMI 2.0 / 3.0 co-simulation through FMPy).

`binding`: the map file (`--fmu-map`) checked against the FMU's modelDescription.xml and the
databases before anything runs; the FMU's parameters as the `ecu.fmu.<instance>.*` subtree.
`function`: the EcuFunction that steps the FMU on the ECU's 1 ms tick (FMI 2.0 section 4.2.2
fmi2DoStep, FMI 3.0 section 4.2.1 fmi3DoStep) and sends its outputs at their cycle times.
FMPy and pint (unit conversion) are imported only when an FMU is given (`pip install vecu[fmu]`).
"""

"""Laser / TEC / HV controller on Modbus TCP: register map (protocol), typed errors, driver."""

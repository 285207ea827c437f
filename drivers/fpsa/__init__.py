"""FPSA controller (FPGA + HV583) link: pure codec (protocol), typed errors, driver."""

"""Preview rendering (sphere tracing of nested neural SDFs): comes in a later issue."""

"""Performance probes: planning latency, call and kernel profiles, operation counts, start-up and compile cost, the
learned proposal's and filter's timing, the machine's matrix-product rate, the projection split over cores,
simulation speed, the learned prior's overhead and shared-row projection. README.md lists them with the page each
feeds."""

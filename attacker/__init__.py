"""An attacker on the V2X air: a participant of the run that transmits what a receiver must refuse.

    python -m attacker --config scenarios/apps/attacker.toml      # started by `v2i run` (bus from V2I_*)
    python -m attacker --list                                     # the attacks and their parameters

It is a station like the RSU (`[v2x.stations.attacker]`): what it sends on
`v2x/tx/<station>` reaches every other station through the channel model, and
what it hears arrives on `v2x/rx/<station>`. It follows the master's clock in
lockstep, so an attack happens at the same simulated instants in every run.

Attacks are chosen by name (attacker.attacks.ATTACKS): surrogate BSMs of a
ghost vehicle unsigned, signed under a CA of the attacker's own, or signed
with a stolen certificate that has expired; replays of genuine frames it
captured, later and from its own position; a bounded flood of random frames.
Like the apps it imports only `bridges` of the project.
"""

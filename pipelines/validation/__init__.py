"""Method validation, the pipeline glue: an archived run solved again by independent public
implementations (peers), compared parameter by parameter (docs/validation.md)."""

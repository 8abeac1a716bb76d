"""The connected automated vehicle's software (stage 3)."""

"""Onboard controllers: active scale estimation, bearing formation, random-motion baseline."""

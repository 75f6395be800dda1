"""Onboard estimators: relative yaw, SfM inverse-depth observer, localization, consensus."""

"""soil_bringup: Composition: the soil_launch launcher and the main-job demo (launch, live monitor, scoring from the bags, report)."""

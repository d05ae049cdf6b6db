#!/usr/bin/env bash
# The arguments each world's shipped fused-posterior calibration is made with (one home for them:
# scripts/train_models.sh calibrates with them, scripts/check_calibration.sh checks the shipped
# configs against them). Usage: fusion_args WORLD -> prints them, one per line.
fusion_args() {
    case "$1" in
        # the surcharge relief term soil_discrepancy proposed (docs/soil_posterior.md)
        default) printf '%s\n' --term "form:-qnq*tanhvx0.1=0.756" ;;
        # soils without cohesion 0.1 of the prior (a little cohesion was taken for none) and the
        # stiff row 0.04 (docs/soil_posterior.md, "Soils with a little cohesion")
        fee) printf '%s\n' --set cohesionless_prior=0.1 --set stiff_prior=0.04 ;;
        *) echo "fusion_args: unknown world '$1'" >&2; return 2 ;;
    esac
}

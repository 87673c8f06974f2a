"""Model edges against image edges, below both the trackers and the regressors (roles never import
each other): which model edges are visible at a pose (:class:`ModelView`), the search for image edges
along their normals, the moving-edge fit (:func:`fit_edges`; coarse to fine over an image pyramid:
:func:`coarse_to_fine`) and how much of the image it explains
(:func:`explained_edge_share`, and of its lit pixels: :func:`explained_lit_share`, which also tells
whether something lit stands beside the object: :func:`lit_verdict`; under a known sun
the surface it lights, cast shadows included, against the image's: :func:`sunlit_mask`,
:func:`sunlit_agreement`), and how far its
edges lie from the image's (:func:`edge_distances_px`, the check of a track on real video); whether the
image singles a pose out from its own view slid beside it (:func:`placement_contrast`, the check of a start). The edge trackers follow the object with it; the CNN regressor
refines its pose and chooses between end-for-end twins with it.
"""
from .fit import (
    EdgeFit,
    EdgeSites,
    explained_edge_share,
    fit_edges,
    fit_from_proposals,
    printed_faces,
    search_edges,
    to_gray,
)
from .image import to_gray8
from .distinct import edge_support, placement_contrast
from .quality import honest_quality, quality_verdict
from .image_distance import edge_distances_px
from .model_view import EdgeSamples, ModelView
from .pyramid import coarse_to_fine, projected_diagonal_px
from .shadows import sunlit_agreement, sunlit_mask
from .silhouette import explained_lit_share, lit_verdict

__all__ = ["EdgeFit", "EdgeSamples", "EdgeSites", "ModelView", "coarse_to_fine", "edge_distances_px", "edge_support", "explained_edge_share",
           "explained_lit_share", "fit_edges", "fit_from_proposals", "honest_quality", "lit_verdict", "placement_contrast",
           "printed_faces", "projected_diagonal_px", "quality_verdict", "search_edges",
           "sunlit_agreement", "sunlit_mask", "to_gray", "to_gray8"]

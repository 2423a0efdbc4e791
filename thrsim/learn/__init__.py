"""The learned reaming simulator [7.3]: a Graph Network over the bone's tetrahedra and a reamer-advance regressor.

Modules, MeshGraphNets-style: ``graph`` (the static graph, built once from the mesh, and the
region near the reamer), ``features`` (per-frame node, edge and global inputs), ``network``
(the pure encode–process–decode Graph Network and the node-wise MLP baseline),
``learned_simulator`` (normalisation, pre/post-processing, threshold), ``advance`` (the
reamer-advance regressor), ``rollout`` (one frame after another), ``training``,
``evaluation``, ``model_dir`` (weights, card and mesh on disk), ``simulator`` (the interactive
:class:`ReamingSimulator`), ``vtk_series`` (ParaView output) and ``bench``.
"""

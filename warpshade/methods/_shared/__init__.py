"""What more than one method package builds on, below the methods that use it.

A method package imports no other method package's modules; a piece that two methods need lives
here (or lower: :mod:`warpshade.basis`, :mod:`warpshade.transfer`, :mod:`warpshade.methods._common`)
with the methods that use it named in its module docstring. Nothing here imports a method
package. The package is not a method (:data:`warpshade.methods.METHOD_PACKAGES` skips
``_``-prefixed packages) and is internal: the public names among its contents are re-exported
by the method packages that introduced them (``warpshade.methods.datadriven``).

Today it holds what the data-driven methods (:mod:`warpshade.methods.datadriven`,
:mod:`warpshade.methods.visibility`) learn from:

* :mod:`.pose` -- pose vectors of a skinned scene (three parameterisations, root apart);
* :mod:`.pose_kernels` -- the same pose vectors on the device, per frame;
* :mod:`.pose_space` -- standardisation and PCA of pose vectors, and the novelty of new poses;
* :mod:`.training` -- the training clip: its stage parameter, its frame selection, the checks
  that a clip holds the graph's character, and the ray-traced training data as executor tasks.
"""

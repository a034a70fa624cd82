"""The datasets: where Shelf's and Campus' files live, their fixed facts and ground truth, Campus as
a 2D sequence."""
